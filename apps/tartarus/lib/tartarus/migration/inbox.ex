defmodule Tartarus.Migration.Inbox do
  @moduledoc """
  Exactly-once hand-over of messages to a moving agent, as pure functions.

  A sender tags each message once (`Tartarus.Locator` numbers them in the order it sends,
  per node) and sends it again, with the same tag, wherever the agent went when the process
  it sent it to ends. The agent takes a tag once: the inbox remembers the last tag taken
  from each recent sender (a sender has one message outstanding at a time), and that memory
  travels with the agent from process to process inside the `commit` message
  (`Tartarus.Migration.Messages.commit/4`), together with the messages the old process took
  and had not handled. The successor handles those before anything else. A copy that
  reaches the old process after the hand-over is lost with it and sent again by its sender
  (the old process's exit names its successor). So each message is handled once wherever
  the agent runs, and a sender's messages in the order it sent them.

  A message here is `{:"$tartarus_msg", {sender_pid, tag}, kind, body}` with `kind` in
  `:post | :request`.

      iex> alias Tartarus.Migration.Inbox
      iex> pid = self()
      iex> {true, i} = Inbox.take(Inbox.new(), {pid, 1})
      iex> {false, i} = Inbox.take(i, {pid, 1})
      iex> {false, _} = Inbox.take(i, {pid, 0})
      iex> {true, _} = Inbox.take(i, {pid, 2})
  """

  # Senders remembered before the memory is trimmed at all, and how long a sender is kept
  # after its last message was taken (however many others came since).
  @max 1024
  @keep_ms 60_000

  @typedoc """
  The memory of what was taken: sender => {order, last tag, when taken (system time, ms)},
  the order counter, and the size past which it is next trimmed.
  """
  @type t :: %{
          seen: %{optional(pid()) => {non_neg_integer(), term(), integer()}},
          n: non_neg_integer(),
          limit: pos_integer()
        }

  @doc "An empty inbox."
  @spec new() :: t()
  def new, do: %{seen: %{}, n: 0, limit: @max}

  @doc """
  Whether a message from `{pid, tag}` is new (then it is remembered as taken, at `now`). A
  sender's tags grow, so a tag at or under the last one taken from that sender is old: a
  copy sent again that arrives after the sender's next message was taken is not taken a
  second time.

  The memory is bounded by time, not by a count: past #{@max} senders it drops those
  whose last message was taken over #{div(@keep_ms, 1000)} s ago (and never one whose
  message the agent still holds, see `handover/4`). A sender sends a message again only
  until it is acknowledged, right after the agent's process that had it ends; so a copy
  sent again reaches the agent well within that time, and is not taken twice, whatever the
  number of senders (a cast is a sender of its own).
  """
  @spec take(t(), {pid(), term()}, integer()) :: {boolean(), t()}
  def take(%{seen: seen} = inbox, {pid, tag}, now \\ Tartarus.Clock.system_time(:millisecond)) do
    if taken?(inbox, {pid, tag}) do
      {false, inbox}
    else
      n = inbox.n + 1
      {true, trim(%{inbox | seen: Map.put(seen, pid, {n, tag, now}), n: n}, now, %{})}
    end
  end

  @doc """
  Whether a message from `{pid, tag}` was taken already (`take/3` would not take it):
  a copy its sender sent again.

      iex> alias Tartarus.Migration.Inbox
      iex> {true, i} = Inbox.take(Inbox.new(), {self(), 5})
      iex> {Inbox.taken?(i, {self(), 5}), Inbox.taken?(i, {self(), 4}), Inbox.taken?(i, {self(), 6})}
      {true, true, false}
  """
  @spec taken?(t(), {pid(), term()}) :: boolean()
  def taken?(%{seen: seen}, {pid, tag}) do
    case Map.fetch(seen, pid) do
      {:ok, entry} when elem(entry, 1) == tag -> true
      {:ok, entry} when is_integer(elem(entry, 1)) and is_integer(tag) -> tag < elem(entry, 1)
      _ -> false
    end
  end

  # Past the limit: senders taken longer ago than @keep_ms go, except those in `keep` (the
  # senders of messages the agent still holds); the next trim waits until the memory has
  # doubled (so a memory of young senders is not scanned at every take).
  defp trim(%{seen: seen, limit: limit} = inbox, _now, _keep) when map_size(seen) <= limit,
    do: inbox

  defp trim(%{seen: seen} = inbox, now, keep) do
    cutoff = now - @keep_ms

    seen =
      :maps.filter(
        fn pid, entry -> is_map_key(keep, pid) or taken_at(entry) >= cutoff end,
        seen
      )

    %{inbox | seen: seen, limit: max(@max, 2 * map_size(seen))}
  end

  defp taken_at({_, _, at}), do: at
  defp taken_at(_), do: 0

  @doc """
  Takes the new messages of `msgs` (a list, proper or not, from anywhere), in order;
  anything that is not a well-formed message is left out.
  """
  @spec take_new(t(), term()) :: {[tuple()], t()}
  def take_new(inbox, msgs), do: take_new(inbox, msgs, [])

  defp take_new(inbox, [m | rest], acc) do
    case take_msg(inbox, m) do
      {true, inbox} -> take_new(inbox, rest, [m | acc])
      {false, inbox} -> take_new(inbox, rest, acc)
    end
  end

  defp take_new(inbox, _, acc), do: {Enum.reverse(acc), inbox}

  @doc "`take/2` for a whole message; false for anything that is not one."
  @spec take_msg(t(), term()) :: {boolean(), t()}
  def take_msg(inbox, {:"$tartarus_msg", {pid, _} = from, kind, _})
      when is_pid(pid) and kind in [:post, :request],
      do: take(inbox, from)

  def take_msg(inbox, _), do: {false, inbox}

  @doc """
  What a running agent does with `msg`, a message from its mailbox (`Tartarus.Agent.Server`
  in `:running`): `{:handle, m, inbox}`, a message of the agent's, new, to handle now;
  `:taken`, a copy of one it took already (nothing to do); `{:pending, msgs, inbox}`, a
  commit that came after the process stopped waiting for it, whose hand-over's new
  messages are handled next, in order (what it took meanwhile is not taken twice); `:junk`,
  a malformed message for the agent (counted as dropped); `:protocol`, a late or repeated
  message of a hand-off (ignored); `:other`, anything else (the agent's code's).

      iex> alias Tartarus.Migration.Inbox
      iex> m = {:"$tartarus_msg", {self(), 1}, :post, :hi}
      iex> {:handle, ^m, i} = Inbox.running(Inbox.new(), m)
      iex> {Inbox.running(i, m), Inbox.running(i, {:"$tartarus_msg", :bad})}
      {:taken, :junk}
      iex> {:pending, [], _} = Inbox.running(i, {:"$tartarus_commit", :mig, :c, nil, {[m], i}})
  """
  @spec running(t(), term()) ::
          {:handle, tuple(), t()}
          | {:pending, [tuple()], t()}
          | :taken
          | :junk
          | :protocol
          | :other
  def running(inbox, {:"$tartarus_msg", {pid, _} = from, kind, _} = m)
      when is_pid(pid) and kind in [:post, :request] do
    case take(inbox, from) do
      {true, inbox} -> {:handle, m, inbox}
      {false, _} -> :taken
    end
  end

  def running(inbox, {:"$tartarus_commit", _mig, _copy, _notify, {msgs, _}})
      when is_list(msgs) do
    {msgs, inbox} = take_new(inbox, msgs)
    {:pending, msgs, inbox}
  end

  def running(_inbox, msg) when is_tuple(msg) and elem(msg, 0) == :"$tartarus_msg", do: :junk

  def running(_inbox, msg) do
    if Tartarus.Migration.Messages.protocol_message?(msg), do: :protocol, else: :other
  end

  @doc """
  The hand-over a process that moves away sends its successor inside `commit`:
  `pending` (messages it took and had not handled) followed by the new ones of `mailbox`
  (what it drained from its mailbox), and its memory.
  """
  @spec handover(t(), [tuple()], [tuple()], integer()) :: {[tuple()], t()}
  def handover(inbox, pending, mailbox, now \\ Tartarus.Clock.system_time(:millisecond)) do
    {fresh, inbox} = take_new(inbox, mailbox)
    msgs = pending ++ fresh
    keep = for {:"$tartarus_msg", {pid, _}, _, _} <- msgs, into: %{}, do: {pid, true}
    {msgs, trim(inbox, now, keep)}
  end

  @doc """
  What a successor handles first when it starts: the hand-over's messages, then the new
  ones among those it got while it waited (`stashed`), with the hand-over's memory. A
  missing or malformed hand-over counts as an empty one.
  """
  @spec arrive(t(), term(), [tuple()]) :: {[tuple()], t()}
  def arrive(inbox, handover, stashed) do
    {handed, inbox} = receive_handover(inbox, handover)
    {fresh, inbox} = take_new(inbox, stashed)
    {handed ++ fresh, inbox}
  end

  @doc """
  The successor's inbox and the messages it handles first, from a received hand-over
  (anything malformed counts as an empty one).
  """
  @spec receive_handover(t(), term()) :: {[tuple()], t()}
  def receive_handover(_inbox, {msgs, %{seen: seen, n: n} = inbox})
      when is_list(msgs) and is_map(seen) and is_integer(n),
      do: {msgs, %{seen: seen, n: n, limit: max(Map.get(inbox, :limit, @max), @max)}}

  def receive_handover(inbox, _), do: {[], inbox}
end
