defmodule Tartarus.Migration.InboxModelTest do
  # Exactly-once hand-over of messages to a moving agent, model-checked: random walks of one
  # agent that keeps moving (a chain of processes: running, handing off, paused, gone) and
  # senders that each post their messages one at a time, over a network that delays and
  # reorders. The agent's side is the platform's own code: Tartarus.Migration.Inbox decides
  # what a running process takes (running/2, as Tartarus.Agent.Server calls it), what a process that moves away hands over (handover/3, as
  # the executor's live backend calls it) and what its successor handles first (arrive/3,
  # as Tartarus.Agent.Server calls it). The senders do what Tartarus.Locator does: send with
  # one tag, and send again to the successor when the process they sent to ends having
  # moved on (or to the agent's current process when it ended otherwise).
  #
  # Invariants: no message is handled twice (checked at every handling); once the walk
  # quiesces every message of every sender was handled exactly once, in each sender's order.
  # (Dropping one message of a hand-over, or handing over without the memory, fails them.)
  use ExUnit.Case, async: true

  alias Tartarus.Migration.Inbox

  doctest Tartarus.Migration.Inbox

  @walks 300
  @senders 3
  @per_sender 6

  setup_all do
    pids = for _ <- 1..@senders, do: spawn(fn -> receive(do: (:never -> :ok)) end)
    on_exit(fn -> Enum.each(pids, &Process.exit(&1, :kill)) end)
    %{senders: pids}
  end

  test "every message handled exactly once, in each sender's order, over random walks", ctx do
    for seed <- 1..@walks do
      w = walk(seed, ctx.senders)
      msgs = for s <- 1..@senders, seq <- 1..@per_sender, do: {s, seq}

      for m <- msgs do
        assert Map.get(w.handled, m, 0) == 1,
               "seed #{seed}: #{inspect(m)} handled #{Map.get(w.handled, m, 0)} times; " <>
                 "last events: #{inspect(Enum.take(w.trace, 12))}"
      end

      for s <- 1..@senders do
        assert Enum.reverse(w.order[s]) == Enum.to_list(1..@per_sender), "seed #{seed}: order"
      end
    end
  end

  # Casts are senders of their own (a process each): thousands of one-message senders. A
  # copy sent again after many others were taken must still not be taken twice (a memory
  # bounded by a count of senders forgot them: 28,000 duplicates of 10,000 casts to an agent
  # hopping at every arrival, in `mix tartarus.bench busy --cast`).
  test "thousands of one-message senders: a copy sent again is not taken twice" do
    senders = for _ <- 1..5_000, do: spawn(fn -> :ok end)
    msgs = for {pid, i} <- Enum.with_index(senders), do: {:"$tartarus_msg", {pid, i}, :post, i}
    now = System.system_time(:millisecond)

    inbox =
      Enum.reduce(msgs, Inbox.new(), fn m, inbox ->
        {true, inbox} = Inbox.take_msg(inbox, m)
        inbox
      end)

    # Handed over (the memory travels), then every copy sent again: none is new.
    {[], inbox} = Inbox.handover(inbox, [], [])
    {[], inbox} = Inbox.arrive(Inbox.new(), {[], inbox}, [])
    assert Enum.all?(msgs, fn m -> Inbox.take_msg(inbox, m) |> elem(0) == false end)

    # A minute later their memory may go: the next senders trim it once it has doubled.
    later = now + 61_000

    inbox =
      Enum.reduce(1..12_000, inbox, fn i, inbox ->
        {true, inbox} = Inbox.take(inbox, {spawn(fn -> :ok end), i}, later)
        inbox
      end)

    refute Enum.any?(senders, &is_map_key(inbox.seen, &1))
  end

  # -- the walk ------------------------------------------------------------------------

  defp walk(seed, sender_pids) do
    w = %{
      rng: :rand.seed_s(:exsss, {seed, 7, 1}),
      procs: %{1 => proc(:running)},
      current: 1,
      n: 1,
      net: [],
      senders:
        Map.new(Enum.with_index(sender_pids, 1), fn {pid, s} ->
          {s, %{pid: pid, seq: 1, waiting: false, target: nil}}
        end),
      handled: %{},
      order: Map.new(1..@senders, &{&1, []}),
      trace: []
    }

    w = Enum.reduce(1..400, w, fn _, w -> step(w) end)
    quiesce(w, 2_000)
  end

  defp proc(state), do: %{state: state, inbox: Inbox.new(), pending: [], mailbox: [], stash: []}

  defp step(w) do
    {x, w} = uniform(w)

    cond do
      x < 0.25 -> send_next(w)
      x < 0.50 -> deliver(w)
      x < 0.70 -> take(w)
      x < 0.80 -> prepare(w)
      x < 0.90 -> commit(w)
      x < 0.93 -> abort(w)
      true -> follow(w)
    end
  end

  defp quiesce(w, 0), do: w

  defp quiesce(w, n) do
    done? = Enum.all?(w.senders, fn {_, s} -> s.seq > @per_sender end)
    if done?, do: w, else: quiesce(w |> send_all() |> drain() |> follow_all() |> settle(), n - 1)
  end

  defp send_all(w), do: Enum.reduce(Map.keys(w.senders), w, &send_next(&2, &1))
  defp follow_all(w), do: Enum.reduce(Map.keys(w.senders), w, &follow(&2, &1))

  defp drain(%{net: []} = w), do: w
  defp drain(w), do: drain(deliver(w))

  # A move in progress commits, and the running process takes everything it has.
  defp settle(w) do
    w = if w.procs[w.current].state == :paused, do: commit(w), else: w
    take_all(w, 10_000)
  end

  defp take_all(w, 0), do: w

  defp take_all(w, n) do
    p = w.procs[w.current]

    if p.state == :running and (p.pending != [] or p.mailbox != []),
      do: take_all(take(w), n - 1),
      else: w
  end

  # -- senders (as Tartarus.Locator) -----------------------------------------------------

  defp send_next(w), do: with({s, w} <- pick(w, Map.keys(w.senders)), do: send_next(w, s))

  defp send_next(w, s) do
    sender = w.senders[s]

    if sender.waiting or sender.seq > @per_sender do
      w
    else
      # Found where the agent is now (a paused copy is as good: it keeps what it gets).
      w = put_in(w.senders[s], %{sender | waiting: true, target: w.current})
      post(w, s)
    end
  end

  defp post(w, s) do
    %{pid: pid, seq: seq, target: to} = w.senders[s]
    msg = {:"$tartarus_msg", {pid, seq}, :post, {s, seq}}
    %{w | net: [{to, msg} | w.net]}
  end

  # A sender whose process ended: again to its successor, or to where the agent is now.
  defp follow(w), do: with({s, w} <- pick(w, Map.keys(w.senders)), do: follow(w, s))

  defp follow(w, s) do
    sender = w.senders[s]

    case sender.waiting && w.procs[sender.target] do
      %{state: {:gone, next}} ->
        w = put_in(w.senders[s].target, next || w.current)
        note(post(w, s), {:follow, s, sender.target, next})

      _ ->
        w
    end
  end

  # -- the network -----------------------------------------------------------------------

  defp deliver(%{net: []} = w), do: w

  defp deliver(w) do
    {i, rng} = :rand.uniform_s(length(w.net), w.rng)
    {{to, msg}, net} = List.pop_at(w.net, i - 1)
    w = %{w | net: net, rng: rng}

    case w.procs[to].state do
      {:gone, _} -> note(w, {:lost, to, msg})
      :paused -> update_in(w.procs[to].stash, &(&1 ++ [msg]))
      _ -> update_in(w.procs[to].mailbox, &(&1 ++ [msg]))
    end
  end

  # -- the agent -------------------------------------------------------------------------

  # The running process takes the next message: what it was handed first, then its mailbox.
  defp take(w) do
    c = w.current
    p = w.procs[c]

    cond do
      p.state != :running ->
        w

      p.pending != [] ->
        [m | rest] = p.pending
        w = put_in(w.procs[c].pending, rest)
        handle(w, m)

      p.mailbox != [] ->
        [m | rest] = p.mailbox
        w = put_in(w.procs[c].mailbox, rest)

        case Inbox.running(p.inbox, m) do
          {:handle, m, inbox} -> handle(put_in(w.procs[c].inbox, inbox), m)
          :taken -> note(w, {:not_again, m})
        end

      true ->
        w
    end
  end

  defp handle(w, {:"$tartarus_msg", _, :post, {s, seq} = m}) do
    n = Map.get(w.handled, m, 0) + 1
    if n > 1, do: flunk("#{inspect(m)} handled twice; last events: #{inspect(w.trace)}")
    w = %{w | handled: Map.put(w.handled, m, n), order: Map.update!(w.order, s, &[seq | &1])}
    # Acknowledged (before the process could end: a sender sees it before any :DOWN).
    w =
      if w.senders[s].seq == seq,
        do: update_in(w.senders[s], &%{&1 | seq: seq + 1, waiting: false}),
        else: w

    note(w, {:handled, m})
  end

  # The running process starts a hand-off: a paused copy exists at the destination; the
  # source takes nothing meanwhile (it waits for the answer), its mailbox fills.
  defp prepare(w) do
    c = w.current

    if w.procs[c].state == :running do
      n = w.n + 1
      w = %{w | n: n, procs: Map.put(w.procs, n, proc(:paused))}
      w = put_in(w.procs[c].state, {:handing_off, n})
      note(%{w | current: n}, {:prepare, c, n})
    else
      w
    end
  end

  # The commit: the source hands over (Inbox.handover/3: what it took and had not handled,
  # then the new ones in its mailbox) inside it and ends; the copy starts (Inbox.arrive/3).
  defp commit(w) do
    with {src, %{state: {:handing_off, copy}}} <- source_of(w, w.current) do
      p = w.procs[src]
      {msgs, inbox} = Inbox.handover(p.inbox, p.pending, p.mailbox)
      w = put_in(w.procs[src], %{p | state: {:gone, copy}, pending: [], mailbox: []})
      q = w.procs[copy]
      {pending, inbox} = Inbox.arrive(q.inbox, {msgs, inbox}, q.stash)
      w = put_in(w.procs[copy], %{q | state: :running, inbox: inbox, pending: pending, stash: []})
      note(w, {:commit, src, copy, length(pending)})
    else
      _ -> w
    end
  end

  # The hand-off aborts: the copy (and what it stashed) goes; the source runs on.
  defp abort(w) do
    with {src, %{state: {:handing_off, copy}}} <- source_of(w, w.current) do
      w = put_in(w.procs[copy].state, {:gone, nil})
      w = put_in(w.procs[src].state, :running)
      note(%{w | current: src}, {:abort, src, copy})
    else
      _ -> w
    end
  end

  defp source_of(w, copy) do
    Enum.find(w.procs, fn {_, p} -> p.state == {:handing_off, copy} end)
  end

  # -- helpers ---------------------------------------------------------------------------

  defp uniform(w) do
    {x, rng} = :rand.uniform_s(w.rng)
    {x, %{w | rng: rng}}
  end

  defp pick(w, list) do
    {i, rng} = :rand.uniform_s(length(list), w.rng)
    {Enum.at(list, i - 1), %{w | rng: rng}}
  end

  defp note(w, event), do: %{w | trace: Enum.take([event | w.trace], 40)}
end
