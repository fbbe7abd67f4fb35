defmodule Tartarus.Agent.Held do
  @moduledoc false
  # What an agent keeps for later while it hands off (Tartarus.Agent.Server, :handing_off):
  # its messages (post, request) in data.held, newest first, which a committed move hands
  # over with its commit (Tartarus.Migration.Source.handover/1) and a failed one handles
  # afterwards in their order; every other event (calls, casts, other messages) is
  # postponed: gen_statem keeps it and takes it again once the state changes. data.held_size
  # and data.postponed count each, {count, bytes}.
  #
  # Together they are bounded by the hop's stash bound (Tartarus.Migration.Arrival
  # .stash_bound/1: the host options :max_held and :max_held_bytes, the first also the
  # paused copy's stash_max): at most that many events of at most that many bytes (external
  # size: binaries count whole, wherever they live). Beyond that, a message for the agent
  # is refused to its sender (post and request return {:error, {:overloaded, id}}), a call
  # answered the same, anything else dropped and counted: the agent is never killed for
  # what others send it. This module decides and does the refusing; the server turns the
  # rest into its state machine's terms.

  alias Tartarus.Ledger
  alias Tartarus.Migration.{Arrival, Inbox}

  @doc false
  # The fields of an agent's data for this module, empty.
  @spec empty() :: map()
  def empty, do: %{held: [], held_size: {0, 0}, postponed: {0, 0}}

  @doc false
  # Event `event` ({type, content}) of a handing-off agent: {:held, data} (an agent's
  # message, kept in data.held), {:postponed, data} (anything else, to postpone), :taken (a
  # copy of a message the agent took already: dropped, not counted) or :refused (over the
  # bound: refused or dropped, counted).
  @spec keep(map(), {term(), term()}) ::
          {:held, map()} | {:postponed, map()} | :taken | :refused
  def keep(data, event) do
    {held_n, held_bytes} = data.held_size
    {post_n, post_bytes} = data.postponed
    size = bytes(event)
    {max_n, max_bytes} = Arrival.stash_bound(data.host)

    cond do
      # A copy sent again of a message taken already (its sender followed the agent here
      # after the hand-over that carried it): nothing to keep, nothing to count.
      taken?(data, event) ->
        :taken

      held_n + post_n >= max_n or held_bytes + post_bytes + size > max_bytes ->
        refuse(data, event)

      agent_message?(event) ->
        {:info, m} = event
        {:held, %{data | held: [m | data.held], held_size: {held_n + 1, held_bytes + size}}}

      true ->
        {:postponed, %{data | postponed: {post_n + 1, post_bytes + size}}}
    end
  end

  @doc false
  # When the hand-off ends: {the events the agent takes next, in this order, the postponed
  # count, data emptied (data.pending too)}. The events ({type, content}, as gen_statem's)
  # are the messages of a hand-over it had taken and not handled when it left again
  # ({:internal, {:pending, m}}), then what it held, oldest first ({:info, m}); the postponed
  # events come after them (gen_statem's). If the agent stays, that is what it handles, in
  # that order; if it moved, they went with its commit (hand_over/2) and this is not used.
  # (An agent that hands off again at once keeps counting its postponed events, which stay
  # postponed: Tartarus.Agent.Server.)
  @spec release(map()) :: {list(), {non_neg_integer(), non_neg_integer()}, map()}
  def release(data) do
    pending = for m <- data.pending, do: {:internal, {:pending, m}}
    held = for m <- Enum.reverse(data.held), do: {:info, m}
    {pending ++ held, data.postponed, %{Map.merge(data, empty()) | pending: []}}
  end

  @doc false
  # A committed move's hand-over (inside its commit, Tartarus.Migration.Source): the messages
  # the agent took and had not handled (data.pending), then the new ones of what it held and
  # of `mailbox` (what reached it since, drained), with the memory of what was taken
  # (Tartarus.Migration.Inbox.handover/4). Returns {handover, data}.
  @spec hand_over(map(), list()) :: {{list(), map()}, map()}
  def hand_over(data, mailbox) do
    {msgs, inbox} = Inbox.handover(data.inbox, data.pending, Enum.reverse(data.held, mailbox))
    {{msgs, inbox}, %{data | inbox: inbox, pending: []}}
  end

  defp agent_message?({:info, {:"$tartarus_msg", {pid, _}, kind, _}})
       when is_pid(pid) and kind in [:post, :request],
       do: true

  defp agent_message?(_event), do: false

  defp taken?(data, {:info, {:"$tartarus_msg", {pid, _} = from, _kind, _}}) when is_pid(pid),
    do: Inbox.taken?(data.inbox, from)

  defp taken?(_data, _event), do: false

  defp bytes({:info, {:"$tartarus_msg", _from, _kind, msg}}), do: :erlang.external_size(msg)
  defp bytes({_type, content}), do: :erlang.external_size(content)

  defp refuse(data, {:info, {:"$tartarus_msg", {pid, ref}, _kind, _msg}}) when is_pid(pid) do
    send(pid, {ref, {:failed, {:overloaded, data.env.id}}})
    dropped(data)
  end

  defp refuse(data, {{:call, from}, _request}) do
    Tartarus.Events.reply(from, {:error, {:overloaded, data.env.id}})
    dropped(data)
  end

  defp refuse(data, _event), do: dropped(data)

  defp dropped(data) do
    Ledger.count(data.host, :dropped)
    :refused
  end
end
