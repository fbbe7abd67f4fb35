defmodule Tartarus.Migration.ProtocolModel do
  @moduledoc false
  # An explorer of Tartarus.Migration.Protocol with no nodes and no processes: hosts,
  # agents, paused copies and a network are plain data; every protocol decision is made by
  # the protocol's own pure functions (and the journal is folded by
  # Tartarus.Host.Persistence.apply_record/2, as a host replays it). A random walk (seeded)
  # interleaves protocol steps with faults: the network drops, duplicates, delays and
  # reorders messages and replays any message it ever carried (to the current server of
  # the host it was sent to, from an attacker outside every partition); hosts crash and
  # restart (with or without persistence); links partition and heal. Running copies
  # acknowledge their commits (which frees the source's records); copies left in doubt park
  # after a few unanswered queries (small park_after) and their host asks for them.
  #
  # Invariants, after every event:
  #   * never two running copies of one agent;
  #   * no decision changes once made: a commit is written once per migration and names one
  #     copy; every committed answer names that copy, a copy starts only if it is that copy,
  #     and a copy aborts only if it is not (without persistence, a later incarnation of a
  #     crashed source may say aborted to it: the agent died with that source);
  # and after the faults stop (partitions healed, crashed hosts restarted, messages
  # delivered, timers fired): every agent runs exactly once, except, without persistence,
  # agents a crash could take (they were on, or in doubt about, a host when it crashed); and
  # every message posted to an agent no crash took is handled exactly once.
  #
  # Every role runs the platform's own executor (Tartarus.Migration.Executor) with this
  # module as the in-memory backend of all four (source, admission, paused copy, a host's
  # own part): the effects are the protocol's, in the protocol's order, and during the fault
  # phase a host may crash before any of them (crash_point/4), so an order that a crash could
  # break is found. The agents' messages go through the live Tartarus.Agent.Held (kept while
  # handing off, released after a failed hand-off, handed over inside the commit) and
  # Tartarus.Migration.Inbox, the copy's stash and its wait for the source's commit. What
  # Tartarus.Agent.Server decides, the model takes from the same pure functions: a running
  # agent's take (Inbox.running/2: a message, a late commit's hand-over, junk), a handing-off
  # agent's routing (Source.route/2: its hand-off's replies, else Held.keep/2), what it takes
  # after a hand-off that did not move it, in order (Held.release/1); and a host that starts
  # again from its journal starts what HostProtocol.restore/3 says, as
  # Tartarus.Host.Agents.restore/1 does. The gen_statem around them (its postponed queue,
  # inserted events) is the model's bookkeeping (`postponed`).
  #
  # What the backend keeps in its own words is storage, not logic: a host's ledger is
  # `fwd` (under an agent's id, its undecided hand-off record {:handoff, mig, pid} or its
  # forwarding pointer {mig, copy, notify} | :acked: one key, as Tartarus.Ledger has it) and
  # `decisions` (clones' commits and, after a restart, the journal's); its journal is
  # Tartarus.Host.Persistence's fold.

  @behaviour Tartarus.Migration.Executor.Source
  @behaviour Tartarus.Migration.Executor.Destination
  @behaviour Tartarus.Migration.Executor.Copy
  @behaviour Tartarus.Migration.Executor.Host

  alias Tartarus.Host.Persistence
  alias Tartarus.Ledger
  alias Tartarus.Agent.Held
  alias Tartarus.Migration.{CopyProtocol, Executor, HostProtocol, Inbox, Messages, Protocol}
  alias Tartarus.Migration.Source

  # Chance of a crash of the host at each effect of the executor (fault phase).
  @crash_point 0.03

  @hosts [:h1, :h2, :h3]

  defmodule Violation do
    @moduledoc false
    defexception [:what, :trace]
    def message(%{what: what}), do: inspect(what)
  end

  @doc false
  # Runs one walk. Options: :events (fault phase length), :persist, :seen_max (passed to the
  # destination state), :trace (keep the last N events for the report).
  # Returns {:ok, events_executed, stats} or {:violation, what, trace}.
  def walk(seed, opts \\ []) do
    persist = Keyword.get(opts, :persist, rem(seed, 2) == 0)
    n = Keyword.get(opts, :events, 200)
    w = init(seed, persist, opts)

    try do
      w = Enum.reduce(1..n, w, fn _, w -> w |> fault_step() |> check() end)
      w = quiesce(%{w | faulting: false})
      check_final(w)
      {:ok, w.events, w.stats}
    rescue
      e in Violation -> {:violation, e.what, e.trace}
    end
  end

  # -- world -------------------------------------------------------------------------

  defp init(seed, persist, opts) do
    rng = :rand.seed_s(:exsss, {seed, 17, 4711})

    w = %{
      rng: rng,
      persist: persist,
      seen_max: Keyword.get(opts, :seen_max, 100_000),
      check_decisions: Keyword.get(opts, :check_decisions, true),
      # Copies park after this many unanswered queries (small: parking is explored often).
      park_after: Keyword.get(opts, :park_after, 2),
      trace_n: Keyword.get(opts, :trace, 60),
      trace: [],
      faulting: true,
      events: 0,
      stats: %{},
      n: 0,
      hosts: %{},
      procs: %{},
      net: [],
      archive: {0, %{}},
      partitions: MapSet.new(),
      decisions: %{},
      msgs: %{},
      known: MapSet.new(),
      exposed: MapSet.new()
    }

    w = Enum.reduce(@hosts, w, fn h, w -> boot(w, h, nil) end)

    # One agent per host to begin with.
    Enum.reduce(@hosts, w, fn h, w ->
      {id, w} = fresh(w, :agent)
      env = %{id: id}
      {pid, w} = fresh(w, :pid)
      w = journal(w, h, {:agent, id, env})
      w = put_in(w.hosts[h].residents[id], pid)
      w = put_in(w.procs[pid], agent_proc(h, env))
      %{w | known: MapSet.put(w.known, id)}
    end)
  end

  defp boot(w, h, journal) do
    {inc, w} = fresh(w, :inc)
    restored = journal || Persistence.empty()
    {agents, in_doubt, decided} = Persistence.restored(restored)

    host = %{
      alive: true,
      inc: inc,
      decisions: Map.new(decided, fn {mig, copy} -> {mig, {:committed, copy}} end),
      parked: %{},
      fwd: %{},
      residents: %{},
      dest: Protocol.destination(seen_max: w.seen_max),
      journal: if(w.persist, do: restored)
    }

    w = put_in(w.hosts[h], host)

    # What it starts, how and in which order: the live host's (Tartarus.Host.Agents.restore/1);
    # the model runs any agent's code.
    Enum.reduce(HostProtocol.restore(agents, in_doubt, fn _env -> true end), w, fn
      {:not_started, []}, w ->
        w

      {:start, env}, w ->
        {pid, w} = fresh(w, :pid)
        start_resident(w, h, pid, env)

      :await_started, w ->
        w

      {:pause, mig, copy, env, src, kind}, w ->
        {pid, w} = fresh(w, :pid)
        c = CopyProtocol.new(mig, copy, src, kind, park_after: w.park_after)
        w = put_in(count(w, :restored_paused).procs[pid], new_copy(h, env, c))
        update_in(w.hosts[h].dest, &Protocol.restore_seen(&1, mig, copy, pid))
    end)
  end

  defp start_resident(w, h, pid, env) do
    if Map.has_key?(w.hosts[h].residents, env.id) do
      w
    else
      w = put_in(w.hosts[h].residents[env.id], pid)
      w = update_in(w.hosts[h].fwd, &Map.delete(&1, env.id))
      put_in(w.procs[pid], agent_proc(h, env))
    end
  end

  defp new_copy(h, env, c),
    do: %{role: :copy, host: h, env: env, c: c, stash: [], postponed: [], data: agent_data(env)}

  # `postponed`: what gen_statem keeps while the agent hands off (Held counts it).
  defp agent_proc(h, env),
    do: %{role: :agent, host: h, env: env, src: nil, postponed: [], data: agent_data(env)}

  # The agent process's fields that Tartarus.Agent.Held and the hand-over read and write.
  defp agent_data(env),
    do: Map.merge(Held.empty(), %{host: %{opts: %{}}, env: env, inbox: Inbox.new(), pending: []})

  defp fresh(w, tag), do: {{tag, w.n}, %{w | n: w.n + 1}}

  defp journal(%{persist: false} = w, _h, _rec), do: w

  defp journal(w, h, rec),
    do: update_in(w.hosts[h].journal, &Persistence.apply_record(rec, &1))

  defp server(w, h), do: {:hs, h, w.hosts[h].inc}

  defp alive_host?(w, h), do: w.hosts[h].alive

  defp pid_host({:hs, h, _}), do: h
  defp pid_host(_), do: nil

  # -- events ------------------------------------------------------------------------

  defp fault_step(w) do
    {x, w} = uniform(w)

    cond do
      x < 0.30 -> deliver_random(w)
      x < 0.40 -> start_handoff(w)
      x < 0.50 -> fire_timer(w)
      x < 0.55 -> net_fault(w, :drop)
      x < 0.60 -> net_fault(w, :dup)
      x < 0.70 -> replay(w)
      x < 0.73 -> crash(w)
      x < 0.80 -> restart(w)
      x < 0.84 -> partition(w)
      x < 0.88 -> heal(w)
      x < 0.92 -> post(w)
      x < 0.94 -> retry(w)
      true -> down(w)
    end
  end

  defp uniform(w) do
    {x, rng} = :rand.uniform_s(w.rng)
    {x, %{w | rng: rng}}
  end

  defp pick(w, []), do: {nil, w}

  defp pick(w, list) do
    {i, rng} = :rand.uniform_s(length(list), w.rng)
    {Enum.at(list, i - 1), %{w | rng: rng}}
  end

  defp note(w, event) do
    stats = Map.update(w.stats, elem(event, 0), 1, &(&1 + 1))
    %{w | events: w.events + 1, stats: stats, trace: Enum.take([event | w.trace], w.trace_n)}
  end

  # Counted, not an event of the walk.
  defp count(w, what), do: %{w | stats: Map.update(w.stats, what, 1, &(&1 + 1))}

  defp deliver_random(w) do
    case w.net do
      [] ->
        w

      net ->
        {i, rng} = :rand.uniform_s(length(net), w.rng)
        {m, net} = List.pop_at(net, i - 1)
        deliver(%{w | rng: rng, net: net}, m)
    end
  end

  # (A sender's resends are not dropped: the link between two live processes is reliable, and
  # a lost connection is a :DOWN, on which the sender resends.)
  defp net_fault(w, kind) do
    case w.net do
      [] ->
        w

      net ->
        {i, rng} = :rand.uniform_s(length(net), w.rng)
        m = Enum.at(net, i - 1)
        w = %{w | rng: rng}

        case kind do
          :drop when elem(m, 2) == :sender -> w
          :drop -> note(%{w | net: List.delete_at(net, i - 1)}, {:drop, m})
          :dup -> note(%{w | net: [m | net]}, {:dup, m})
        end
    end
  end

  # Any message the network ever carried, again, from outside every partition; a message
  # for a host's server goes to its current server (the attacker finds it by address).
  defp replay(w) do
    {count, archive} = w.archive

    if count == 0 do
      w
    else
      {i, rng} = :rand.uniform_s(count, w.rng)
      {to, msg, _from} = Map.fetch!(archive, rem(i - 1, 256))
      w = %{w | rng: rng}
      to = if h = pid_host(to), do: server(w, h), else: to
      note(%{w | net: [{to, msg, :attacker} | w.net]}, {:replay, to, msg})
    end
  end

  defp send_msg(w, from_host, to, msg) do
    {count, archive} = w.archive
    archive = Map.put(archive, rem(count, 256), {to, msg, from_host})
    %{w | net: [{to, msg, from_host} | w.net], archive: {count + 1, archive}}
  end

  defp partitioned?(_w, :attacker, _to), do: false
  defp partitioned?(_w, :sender, _to), do: false

  defp partitioned?(w, a, b),
    do: a != b and MapSet.member?(w.partitions, Enum.sort([a, b]))

  defp deliver(w, {to, msg, from} = m) do
    w = note(w, {:deliver, m})
    to_host = dest_host(w, to)

    cond do
      to_host == nil or not alive_host?(w, to_host) -> w
      partitioned?(w, from, to_host) -> w
      true -> receive_msg(w, to, to_host, msg)
    end
  end

  defp dest_host(w, {:hs, h, inc}), do: if(w.hosts[h].inc == inc, do: h)
  defp dest_host(w, pid), do: with(%{host: h} <- w.procs[pid], do: h)

  defp receive_msg(w, {:hs, h, _}, h, msg) do
    case Messages.classify(msg) do
      {:prepare, p} ->
        admission(w, h, {:prepare, p})

      {:query, mig, id, copy, a_pid} ->
        host_event(w, h, {:query, mig, id, copy, a_pid})

      {:acks, list} ->
        host_event(w, h, {:acks, list})

      {:decision, mig, copy, d} ->
        host_event(w, h, {:decision, mig, copy, d})

      _ ->
        w
    end
  end

  defp receive_msg(w, pid, _h, msg) do
    case w.procs[pid] do
      %{role: :copy} -> copy_info(w, pid, msg)
      %{role: :agent} -> agent_info(w, pid, msg)
    end
  end

  # A message reaches a paused copy: its event (CopyProtocol.event/2), else, while it awaits
  # its source's commit, postponed (as Tartarus.Migration.Arrival.awaited/2), else a stray.
  defp copy_info(w, pid, msg) do
    %{c: c} = w.procs[pid]

    case CopyProtocol.event(c, msg) do
      nil when c.phase == :awaiting -> update_in(w.procs[pid].postponed, &(&1 ++ [msg]))
      nil -> w
      event -> copy_event(w, pid, event)
    end
  end

  # A message reaches an agent's process, as Tartarus.Agent.Server takes it: running, by
  # Tartarus.Migration.Inbox.running/2 (its messages taken once, a late commit's hand-over);
  # handing off, by Tartarus.Migration.Source.route/2 (its hand-off's replies, or
  # Tartarus.Agent.Held: kept, postponed, taken, refused). (The model's sources see their
  # destinations go down by its own event, down/1: no monitor.)
  defp agent_info(w, pid, msg) do
    case w.procs[pid] do
      nil ->
        w

      %{src: nil, data: data} ->
        case Inbox.running(data.inbox, msg) do
          {:handle, m, inbox} ->
            handled(put_in(w.procs[pid].data.inbox, inbox), m)

          {:pending, msgs, inbox} ->
            w = put_in(count(w, :late_commit).procs[pid].data.inbox, inbox)
            Enum.reduce(msgs, w, &handled(&2, &1))

          # A copy sent again of a message it took already.
          :taken ->
            count(w, :taken_again)

          _junk_protocol_or_other ->
            w
        end

      %{src: src, data: data} ->
        case Source.route(Map.put(data, :handoff, {src.s, %{mref: nil}}), {:info, msg}) do
          {:step, event} ->
            source_event(w, pid, event)

          {:held, data} ->
            put_in(w.procs[pid].data, data)

          {:postponed, data} ->
            update_in(count(w, :postponed).procs[pid], &postpone(&1, data, msg))

          _taken_or_refused ->
            w
        end
    end
  end

  defp postpone(proc, data, msg), do: %{proc | data: data, postponed: proc.postponed ++ [msg]}

  # -- source --------------------------------------------------------------------------

  defp start_handoff(w) do
    candidates =
      for {pid, %{role: :agent, src: nil, host: h}} <- w.procs, alive_host?(w, h), do: pid

    {pid, w} = pick(w, Enum.sort(candidates))
    {dest, w} = pick(w, @hosts)
    {x, w} = uniform(w)
    agents = Enum.count(w.procs, fn {_, p} -> p.role == :agent end)
    kind = if x < 0.2 and agents < 6, do: :clone, else: :move

    cond do
      pid == nil ->
        w

      not alive_host?(w, dest) ->
        w

      true ->
        proc = w.procs[pid]
        h = proc.host
        {ref, w} = fresh(w, :ref)
        mig = {w.hosts[h].inc, ref}

        {env, w} =
          if kind == :clone do
            {id, w} = fresh(w, :agent)
            {%{id: id, clone_of: proc.env.id}, w}
          else
            {proc.env, w}
          end

        s = Protocol.source(mig, kind, server(w, dest), nil, proc.env.id, env.id)
        prepare = Messages.prepare(pid, mig, h, server(w, h), kind, env, [], [])
        w = put_in(w.procs[pid].src, %{s: s, prepare: prepare, out: env, dest: dest})
        w = note(w, {:start, pid, proc.env.id, kind, h, dest, mig})
        source_event(w, pid, :begin)
    end
  end

  # The platform's executor carries out the source's actions (this module is its backend).
  defp source_event(w, pid, event) do
    %{src: src} = w.procs[pid]

    case Executor.source_event(src.s, event, %{w: w, pid: pid}, __MODULE__) do
      {:wait, s, %{w: w}} ->
        put_in(w.procs[pid].src.s, s)

      {:done, {:committed, _, _}, %{kind: :move}, %{w: w}} ->
        %{w | procs: Map.delete(w.procs, pid)}

      # It runs on here: it takes what it kept, in Tartarus.Agent.Held.release/1's order,
      # then what gen_statem postponed (Tartarus.Agent.Server).
      {:done, _outcome, _s, %{w: w}} ->
        %{data: data, postponed: postponed} = w.procs[pid]
        {events, _count, data} = Held.release(data)
        w = update_in(w.procs[pid], &%{&1 | src: nil, data: data, postponed: []})
        w = Enum.reduce(events, w, fn _, w -> count(w, :replayed) end)

        Enum.reduce(events ++ Enum.map(postponed, &{:info, &1}), w, fn
          {:info, m}, w -> agent_info(w, pid, m)
          {:internal, {:pending, m}}, w -> handled(w, m)
        end)

      # The source's host crashed in the middle (the process is gone with it).
      {:halted, %{w: w}} ->
        w
    end
  end

  # -- the executor's in-memory backend ----------------------------------------------------
  # Each effect may first crash the source's host (fault phase only).

  defp effect(%{w: w, pid: pid} = ctx, fun) do
    %{host: h} = w.procs[pid]
    crash_point(ctx, h, :source, &fun.(&1, h, &1.procs[pid]))
  end

  # A crash point before an effect of `role` at host `h` (fault phase only): the host
  # crashes and the effects after it do not happen (Executor: {:halt, ctx}); else `fun`.
  defp crash_point(%{w: w} = ctx, h, role, fun) do
    {x, w} = uniform(w)

    if w.faulting and x < @crash_point do
      w = note(count(w, {:crash_point, role}), {:crash_point, h, role})
      throw({:halt, %{ctx | w: crash_host(w, h)}})
    else
      %{ctx | w: fun.(w)}
    end
  end

  # What the source decided, as the oracle the invariants check against: written at the
  # first effect that can make it observable (a journaled commit, which a restart reloads;
  # a move's pointer; a clone's commit once its hand-off record is gone; a commit message),
  # never changed. A clone's commit entry alone is not observable (a query reads the
  # hand-off record first): a crash then loses it, rightly.
  defp decided(w, proc, mig, copy) do
    d = {:committed, copy}

    case Map.fetch(w.decisions, mig) do
      {:ok, ^d} ->
        w

      {:ok, other} ->
        violation(w, {:decision_written_twice, mig, other, d})

      :error ->
        w = %{w | decisions: Map.put(w.decisions, mig, d)}

        if proc.src.s.kind == :clone,
          do: %{w | known: MapSet.put(w.known, proc.src.out.id)},
          else: w
    end
  end

  # As Tartarus.Ledger.begin_handoff/3.
  @impl true
  def begin_handoff(ctx, mig) do
    effect(ctx, fn w, h, proc -> put_in(w.hosts[h].fwd[proc.env.id], {:handoff, mig, ctx.pid}) end)
  end

  # The model's sources see their destinations go down by its own event (down/1).
  @impl true
  def watch(ctx), do: effect(ctx, fn w, _h, _proc -> w end)

  @impl true
  def send_prepare(ctx) do
    effect(ctx, fn w, h, proc -> send_msg(w, h, server(w, proc.src.dest), proc.src.prepare) end)
  end

  @impl true
  def settle(ctx, _event), do: ctx

  @impl true
  def decide(ctx, mig, copy) do
    ctx =
      effect(ctx, fn w, h, proc ->
        if Map.has_key?(w.hosts[h].decisions, mig) do
          violation(w, {:decision_written_twice, mig, w.hosts[h].decisions[mig], copy})
        else
          _ = proc
          put_in(w.hosts[h].decisions[mig], {:committed, copy})
        end
      end)

    {true, ctx}
  end

  @impl true
  def journal_in_doubt(ctx, rec), do: dest_effect(ctx, &journal(&1, &2, rec))

  @impl true
  def journal(ctx, {:decision, mig, _id, copy} = rec) do
    effect(ctx, fn w, h, proc ->
      w = if w.persist, do: decided(w, proc, mig, copy), else: w
      journal(w, h, rec)
    end)
  end

  def journal(ctx, rec), do: effect(ctx, fn w, h, _proc -> journal(w, h, rec) end)

  @impl true
  def pointer_put(ctx, mig, copy, notify) do
    effect(ctx, fn w, h, proc ->
      w = decided(w, proc, mig, copy)
      put_in(w.hosts[h].fwd[proc.env.id], {mig, copy, notify})
    end)
  end

  @impl true
  def leave(ctx) do
    effect(ctx, fn w, h, proc -> update_in(w.hosts[h].residents, &Map.delete(&1, proc.env.id)) end)
  end

  @impl true
  def end_handoff(ctx, mig) do
    effect(ctx, fn w, h, proc ->
      id = proc.env.id

      # A clone's commit is observable once its hand-off record is gone.
      w =
        case w.hosts[h].decisions do
          %{^mig => {:committed, copy}} -> decided(w, proc, mig, copy)
          _ -> w
        end

      case w.hosts[h].fwd do
        %{^id => {:handoff, ^mig, _}} -> update_in(w.hosts[h].fwd, &Map.delete(&1, id))
        _ -> w
      end
    end)
  end

  # The live hand-over (Tartarus.Agent.Held.hand_over/2) of what the agent held and took.
  @impl true
  def hand_over(%{w: w, pid: pid} = ctx, to, {:"$tartarus_commit", mig, copy, notify, nil}) do
    {handover, data} = Held.hand_over(w.procs[pid].data, [])
    ctx = %{ctx | w: put_in(w.procs[pid].data, data)}
    send(ctx, to, Messages.commit(mig, copy, notify, handover))
  end

  @impl true
  def answer(ctx, to, msg), do: dest_effect(ctx, &send_msg(&1, &2, to, msg))

  @impl true
  def send(ctx, to, msg) do
    effect(ctx, fn w, h, proc ->
      w =
        case msg do
          {:"$tartarus_commit", mig, copy, _, _} -> decided(w, proc, mig, copy)
          _ -> w
        end

      send_msg(w, h, to, msg)
    end)
  end

  @impl true
  def fetch_code(ctx, _mods), do: {{:ok, [:code]}, ctx}

  @impl true
  def resend(ctx, code) do
    effect(ctx, fn w, h, proc ->
      send_msg(w, h, server(w, proc.src.dest), Messages.with_code(proc.src.prepare, code))
    end)
  end

  @impl true
  def committed(ctx, _kind, _mig, _copy), do: ctx

  # -- destination -----------------------------------------------------------------------

  # The platform's executor carries out admission (this module is its backend: the
  # context is %{w: world, dest: host}). Each effect that leaves a trace (the copy, its
  # journal record, the answer) may first crash the destination's host (fault phase only).
  defp admission(w, h, event) do
    {d, %{w: w}} =
      Executor.destination_event(w.hosts[h].dest, event, %{w: w, dest: h}, __MODULE__)

    put_in(w.hosts[h].dest, d)
  catch
    {:halt, %{w: w}} -> w
  end

  defp dest_effect(%{dest: h} = ctx, fun), do: crash_point(ctx, h, :destination, &fun.(&1, h))

  @impl true
  def check(%{w: w} = ctx, p) do
    {x, w} = uniform(w)
    {copy, w} = fresh(w, :copy)
    verdict = if p.code == [] and x < 0.2, do: {:need, [:mod]}, else: :ok
    {verdict, copy, %{ctx | w: w}}
  end

  @impl true
  def probe(%{w: w, dest: h} = ctx, _p, _copy, pid),
    do: {match?(%{role: :copy, host: ^h}, w.procs[pid]), ctx}

  @impl true
  def create(%{w: w} = ctx, p, copy) do
    {pid, w} = fresh(w, :pid)
    c = CopyProtocol.new(p.mig, copy, p.src, p.kind, park_after: w.park_after, src_pid: p.s_pid)

    ctx =
      dest_effect(%{ctx | w: w}, fn w, h ->
        put_in(count(w, :copy_created).procs[pid], new_copy(h, p.env, c))
      end)

    {{:ok, pid}, ctx}
  end

  @impl true
  def refuse(%{w: w, dest: h} = ctx, p, reason) do
    w = send_msg(count(w, {:refused, reason}), h, p.s_pid, Messages.refused(p.mig, reason))
    %{ctx | w: w}
  end

  # -- a host's own part: answers, acknowledgements, parked copies -----------------------

  # The platform's executor carries out the host's actions (this module is its backend: the
  # context is %{w: world, host: h}). Each effect may first crash the host (fault phase).
  defp host_event(w, h, event) do
    %{w: w} = Executor.host_event(event, %{w: w, host: h, fetched: nil}, __MODULE__)
    w
  catch
    # A parked record the host took from its table went with the crash: its agent too.
    {:halt, %{w: w, fetched: {_mig, _copy, _src, id}}} ->
      %{w | exposed: MapSet.put(w.exposed, id)}

    {:halt, %{w: w}} ->
      w
  end

  defp host_effect(%{host: h} = ctx, fun), do: crash_point(ctx, h, :host, &fun.(&1, h))

  # What Tartarus.Ledger.decision_view/3 reads, from the model's ledger.
  @impl true
  def read(%{w: w, host: h} = ctx, mig, id, _copy) do
    host = w.hosts[h]

    view = %{
      handoff?: match?({:handoff, ^mig, _}, Map.get(host.fwd, id)),
      decision: Map.get(host.decisions, mig),
      pointer: with({_, _, _} = p <- Map.get(host.fwd, id), do: p)
    }

    {view, ctx}
  end

  @impl true
  def tell(ctx, to, msg) do
    host_effect(ctx, fn w, h ->
      w =
        case msg do
          {:"$tartarus_decision", mig, copy, a} ->
            w
            |> check_answer(h, mig, copy, a)
            |> count({:answer, if(is_tuple(a), do: :committed, else: a)})

          _ ->
            w
        end

      send_msg(w, h, to, msg)
    end)
  end

  # As Tartarus.Ledger.acknowledge/4: the commit of `mig` to `copy` is no longer needed.
  @impl true
  def acknowledge(ctx, mig, id, copy) do
    host_effect(ctx, fn w, h ->
      w = count(w, :ack)

      case Map.get(w.hosts[h].fwd, id) do
        {^mig, ^copy, _} ->
          put_in(w.hosts[h].fwd[id], :acked)

        _ ->
          if Map.get(w.hosts[h].decisions, mig) == {:committed, copy},
            do: update_in(w.hosts[h].decisions, &Map.delete(&1, mig)),
            else: w
      end
    end)
  end

  # A parked copy dropped: its migration must not have been committed to it.
  @impl true
  def record(ctx, {:resolved, mig, copy} = rec) do
    {_mig, _copy, src, _id} = ctx.fetched

    host_effect(ctx, fn w, h ->
      w = check_abort(count(w, :parked_dropped), %{mig: mig, copy: copy, src: src})
      journal(w, h, rec)
    end)
  end

  def record(ctx, rec), do: host_effect(ctx, &journal(&1, &2, rec))

  # Only the copy itself, arriving here, hands over its record.
  @impl true
  def park(ctx, mig, copy, env, src, kind, {pid, _}) do
    %{w: w, host: h} = ctx = host_effect(ctx, fn w, _h -> w end)

    cond do
      not match?(%{role: :copy, host: ^h}, w.procs[pid]) ->
        {:not_here, ctx}

      true ->
        how = if w.hosts[h].parked == %{}, do: :first, else: :more
        w = put_in(count(w, :parked).hosts[h].parked[{mig, copy}], {env, src, kind})
        {how, %{ctx | w: w}}
    end
  end

  # The copy's call returns (park/2 below); the timer is the model's (fire_timer/1).
  @impl true
  def reply_call(ctx, _from, _answer), do: ctx
  @impl true
  def arm_ask(ctx), do: ctx

  @impl true
  def read_parked(%{w: w, host: h} = ctx) do
    records =
      for {{mig, copy}, {env, src, kind}} <- Enum.sort(w.hosts[h].parked),
          do: {mig, copy, env, src, kind}

    {records, ctx}
  end

  @impl true
  def ask(ctx, src, {mig, id, copy}) do
    host_effect(ctx, fn w, h ->
      query = Messages.decision_query(mig, id, copy, server(w, h))
      if alive_host?(w, src), do: send_msg(w, h, server(w, src), query), else: w
    end)
  end

  @impl true
  def fetch_parked(%{w: w, host: h} = ctx, mig, copy) do
    case Map.fetch(w.hosts[h].parked, {mig, copy}) do
      {:ok, {env, src, _kind}} = found -> {found, %{ctx | fetched: {mig, copy, src, env.id}}}
      :error -> {:error, ctx}
    end
  end

  @impl true
  def dropped(ctx), do: ctx

  @impl true
  def unpark(ctx, mig, copy),
    do:
      host_effect(ctx, fn w, h -> update_in(w.hosts[h].parked, &Map.delete(&1, {mig, copy})) end)

  @impl true
  def revive(%{w: w} = ctx, mig, copy, env, src, kind) do
    {pid, w} = fresh(w, :pid)
    c = CopyProtocol.new(mig, copy, src, kind, park_after: w.park_after, claim: true)

    ctx =
      host_effect(%{ctx | w: w}, fn w, h ->
        put_in(count(w, :revived).procs[pid], new_copy(h, env, c))
      end)

    {{:ok, pid}, ctx}
  end

  @impl true
  def arriving(ctx, _id, _pid), do: ctx

  # A committed answer must name the committed copy. (An aborted answer is checked when a
  # copy acts on it: a late answer to a copy that already runs changes nothing.)
  defp check_answer(w, _h, mig, copy, a) do
    made = Map.get(w.decisions, mig)

    if a in [:unknown, :aborted] or made == {:committed, copy} or not w.check_decisions,
      do: w,
      else: violation(w, {:answer_contradicts_decision, mig, copy, a, made})
  end

  # A copy aborts: its migration must not have been committed to it (without persistence a
  # source that crashed since forgot its commit: the agent died with it).
  defp check_abort(w, %{mig: {inc, _} = mig, copy: copy, src: src}) do
    made = Map.get(w.decisions, mig)
    excused = not w.persist and w.hosts[src].inc != inc

    if made != {:committed, copy} or excused or not w.check_decisions,
      do: w,
      else: violation(w, {:committed_copy_aborted, mig, copy})
  end

  # -- paused copies -----------------------------------------------------------------

  # The platform's executor carries out the paused copy's actions (this module is its
  # backend: the context is %{w: world, copy: pid}; the actions that end it return the
  # world). Each effect may first crash the copy's host (fault phase only).
  defp copy_event(w, pid, event) do
    case Executor.copy_event(w.procs[pid].c, event, %{w: w, copy: pid}, __MODULE__) do
      {:paused, %{w: w}} -> w
      {:done, w} -> w
      {:halted, %{w: w}} -> w
    end
  end

  defp copy_effect(%{w: w, copy: pid} = ctx, fun) do
    %{host: h} = w.procs[pid]
    crash_point(ctx, h, :copy, &fun.(&1, h, &1.procs[pid]))
  end

  @impl true
  def copy_state(%{w: w, copy: pid} = ctx, c), do: %{ctx | w: put_in(w.procs[pid].c, c)}

  @impl true
  def become(ctx, handover) do
    copy_effect(ctx, fn w, _h, proc ->
      {pending, inbox} = Inbox.arrive(proc.data.inbox, handover, Enum.reverse(proc.stash))
      data = %{proc.data | inbox: inbox}
      put_in(w.procs[ctx.copy], Map.merge(proc, %{stash: [], data: data, pending: pending}))
    end)
  end

  # A revived copy takes its host's parked record (as Tartarus.Ledger.unpark/3 does).
  @impl true
  def claim(%{copy: pid} = ctx, mig, copy) do
    %{w: w} = ctx = copy_effect(ctx, fn w, _h, _proc -> w end)
    %{host: h} = w.procs[pid]
    parked = w.hosts[h].parked
    taken = Map.has_key?(parked, {mig, copy})
    w = put_in(w.hosts[h].parked, Map.delete(parked, {mig, copy}))
    w = if taken, do: w, else: count(w, :claim_lost)
    {taken, %{ctx | w: w}}
  end

  # The copy runs from here on (as Tartarus.Ledger.register_resident/3: the old pointer of
  # its id goes), unless the agent is resident here already.
  @impl true
  def register(%{copy: pid} = ctx) do
    %{w: w} = ctx = copy_effect(ctx, fn w, _h, _proc -> w end)
    %{host: h, env: env, c: c} = proc = w.procs[pid]

    if w.check_decisions and Map.get(w.decisions, c.mig) != {:committed, c.copy},
      do: violation(w, {:copy_started_without_its_decision, c.mig, c.copy, w.decisions[c.mig]})

    w = note(w, {:copy_starts, pid, env.id, h, c.mig})

    if Map.has_key?(w.hosts[h].residents, env.id) do
      {{:error, :already_resident}, %{ctx | w: w}}
    else
      w = put_in(w.hosts[h].residents[env.id], pid)
      w = update_in(w.hosts[h].fwd, &Map.delete(&1, env.id))
      {:ok, %{ctx | w: put_in(w.procs[pid], Map.merge(proc, %{role: :agent, src: nil}))}}
    end
  end

  # The model's hosts restart from their journals only.
  @impl true
  def put_snapshot(ctx), do: copy_effect(ctx, fn w, _h, _proc -> w end)

  @impl true
  def checkpoint(ctx),
    do: copy_effect(ctx, fn w, h, proc -> journal(w, h, {:agent, proc.env.id, proc.env}) end)

  @impl true
  def drop_arriving(ctx), do: copy_effect(ctx, fn w, _h, _proc -> w end)

  # A copy that does not run ends its record: it aborts, and its migration must not have
  # been committed to it.
  @impl true
  def resolve(ctx, mig, copy) do
    copy_effect(ctx, fn w, h, proc ->
      w = if proc.role == :copy, do: w |> count(:copy_aborted) |> check_abort(proc.c), else: w
      journal(w, h, {:resolved, mig, copy})
    end)
  end

  # (Live, acknowledgements leave in batches; here each is a message of its own.)
  @impl true
  def ack(ctx, src, mig, copy) do
    copy_effect(ctx, fn w, h, proc ->
      if alive_host?(w, src),
        do: send_msg(w, h, server(w, src), Messages.acks([{mig, proc.env.id, copy}])),
        else: w
    end)
  end

  @impl true
  def arrived(ctx), do: copy_effect(ctx, fn w, _h, _proc -> w end)
  @impl true
  def reply(ctx, _notify, _kind), do: copy_effect(ctx, fn w, _h, _proc -> w end)

  # The handed-over messages first, then what was postponed while it awaited the commit.
  @impl true
  def started(%{w: w, copy: pid}, _c) do
    %{pending: pending, postponed: postponed} = w.procs[pid]
    w = update_in(w.procs[pid], &Map.put(Map.drop(&1, [:pending, :stash]), :postponed, []))
    w = Enum.reduce(pending, w, &handled(&2, &1))
    Enum.reduce(postponed, w, &agent_info(&2, pid, &1))
  end

  @impl true
  def await(%{w: w}, _pid), do: count(w, :await)

  @impl true
  def stop(%{w: w, copy: pid}, _reason), do: %{w | procs: Map.delete(w.procs, pid)}

  @impl true
  def ask(%{copy: pid} = ctx, src, mig, copy) do
    copy_effect(ctx, fn w, h, proc ->
      query = Messages.decision_query(mig, Ledger.query_id(proc.env, proc.c.kind), copy, pid)
      if alive_host?(w, src), do: send_msg(w, h, server(w, src), query), else: w
    end)
  end

  # Parked: the host keeps the record (the journal's in-doubt record stays; the copy calls
  # its host's server, which runs the host's part), the process goes.
  @impl true
  def park(%{w: w, copy: pid}, c) do
    %{host: h, env: env} = w.procs[pid]
    w = host_event(w, h, {:park, c.mig, c.copy, env, c.src, c.kind, {pid, :park}})
    %{w | procs: Map.delete(w.procs, pid)}
  end

  # Timers are the model's own events (fire_timer/1).
  @impl true
  def timer(ctx, _ms), do: ctx

  @impl true
  def stash(%{w: w, copy: pid} = ctx, msg),
    do: %{ctx | w: update_in(w.procs[pid].stash, &[msg | &1])}

  @impl true
  def drop(ctx, _msg), do: ctx

  # The host asks the sources of its parked copies (its timer).
  defp ask_parked(w, h), do: host_event(note(w, {:ask_parked, h}), h, :ask_parked)

  # -- the agents' messages ---------------------------------------------------------------
  # A sender posts a message to one of an agent's processes (each message from a sender of
  # its own, one tag) and, while it is not handled, sends it again, with its tag, to the
  # agent's process wherever it is once the process it sent it to is gone (as
  # Tartarus.Locator does). Each message must be handled once, unless a crash took its agent.
  # A resend travels (it may arrive after the agent took the message from a hand-over, and
  # be replayed): Tartarus.Migration.Inbox's memory must make it a no-op.

  defp post(w) do
    {pid, w} = pick(w, Enum.sort(for {pid, p} <- w.procs, alive_host?(w, p.host), do: pid))

    if pid do
      {n, w} = fresh(w, :msg)
      m = {:"$tartarus_msg", {:c.pid(0, 1000 + elem(n, 1), 0), 1}, :post, n}
      w = put_in(w.msgs[n], %{agent: w.procs[pid].env.id, to: pid, handled: 0, m: m})
      agent_receive(note(w, {:post, pid, n}), pid, m)
    else
      w
    end
  end

  # A message reaches an agent's process, as its state machine takes it.
  defp agent_receive(w, pid, {_, _, _, n} = m) do
    w = put_in(w.msgs[n].to, pid)

    case w.procs[pid] do
      nil ->
        w

      %{role: :agent} ->
        agent_info(w, pid, m)

      %{role: :copy} ->
        copy_info(w, pid, m)
    end
  end

  defp handled(w, {_, _, _, n}) do
    w = update_in(w.msgs[n].handled, &(&1 + 1))
    %{agent: id, handled: k} = w.msgs[n]

    if k > 1 and not MapSet.member?(w.exposed, id),
      do: violation(w, {:message_handled_twice, n, id}),
      else: w
  end

  # Senders whose message's process is gone send it again where the agent now is.
  defp retry(w) do
    Enum.reduce(retries(w), w, fn {n, pid}, w ->
      send_msg(put_in(w.msgs[n].to, pid), :sender, pid, w.msgs[n].m)
    end)
  end

  defp retries(w) do
    where =
      for {pid, p} <- w.procs, alive_host?(w, p.host), reduce: %{} do
        acc -> Map.update(acc, p.env.id, pid, &if(p.role == :agent, do: pid, else: &1))
      end

    for {n, %{handled: 0, to: to, agent: id}} <- Enum.sort(w.msgs),
        not Map.has_key?(w.procs, to),
        pid = where[id],
        pid != nil,
        do: {n, pid}
  end

  # -- timers, failures --------------------------------------------------------------

  defp fire_timer(w) do
    timers =
      for {pid, p} <- w.procs,
          alive_host?(w, p.host),
          p.role == :copy or (p.role == :agent and p.src != nil),
          do: pid

    parked = for h <- @hosts, alive_host?(w, h), w.hosts[h].parked != %{}, do: {:parked, h}
    {pid, w} = pick(w, Enum.sort(timers) ++ parked)

    case pid && (match?({:parked, _}, pid) || w.procs[pid]) do
      nil -> w
      true -> ask_parked(w, elem(pid, 1))
      %{role: :copy, c: c} -> copy_event(note(w, {:timer, pid}), pid, CopyProtocol.timeout(c))
      %{role: :agent} -> source_event(note(w, {:timeout, pid}), pid, :timeout)
    end
  end

  # A source whose destination host is gone or cut off may see it go down.
  defp down(w) do
    sources =
      for {pid, %{role: :agent, src: %{dest: d, s: s}, host: h}} <- w.procs,
          alive_host?(w, h),
          s.dest != server(w, d) or not alive_host?(w, d) or partitioned?(w, h, d),
          do: pid

    {pid, w} = pick(w, Enum.sort(sources))
    if pid, do: source_event(note(w, {:down, pid}), pid, {:down, :noconnection}), else: w
  end

  defp crash(w) do
    {h, w} = pick(w, Enum.filter(@hosts, &alive_host?(w, &1)))
    if h == nil, do: w, else: crash_host(w, h)
  end

  defp crash_host(w, h) do
    w = note(w, {:crash, h})

    exposed =
      for({_pid, p} <- w.procs, p.host == h or (p.role == :copy and p.c.src == h), do: p.env.id) ++
        for(
          {g, host} <- w.hosts,
          {_, {env, src, _}} <- host.parked,
          g == h or src == h,
          do: env.id
        )

    procs = Map.reject(w.procs, fn {_, p} -> p.host == h end)
    w = put_in(w.hosts[h].parked, %{})

    %{w | procs: procs, exposed: MapSet.union(w.exposed, MapSet.new(exposed))}
    |> put_in([:hosts, h, :alive], false)
  end

  defp restart(w) do
    {h, w} = pick(w, Enum.reject(@hosts, &alive_host?(w, &1)))
    if h, do: boot(note(w, {:restart, h}), h, w.hosts[h].journal), else: w
  end

  defp partition(w) do
    {a, w} = pick(w, @hosts)
    {b, w} = pick(w, @hosts -- [a])
    note(%{w | partitions: MapSet.put(w.partitions, Enum.sort([a, b]))}, {:partition, a, b})
  end

  defp heal(w) do
    {pair, w} = pick(w, Enum.sort(MapSet.to_list(w.partitions)))

    if pair,
      do: note(%{w | partitions: MapSet.delete(w.partitions, pair)}, {:heal, pair}),
      else: w
  end

  # -- after the faults ----------------------------------------------------------------

  # Partitions heal, crashed hosts restart, every message is delivered and every timer
  # fires, until nothing is in flight and no copy or source is waiting (or 40 rounds).
  defp quiesce(w) do
    w = %{w | partitions: MapSet.new()}

    w =
      Enum.reduce(@hosts, w, fn h, w ->
        if alive_host?(w, h), do: w, else: boot(w, h, w.hosts[h].journal)
      end)

    quiesce(w, 40)
  end

  defp quiesce(w, 0), do: w

  defp quiesce(w, rounds) do
    w = drain(w)

    waiting =
      for {pid, p} <- w.procs, p.role == :copy or (p.role == :agent and p.src != nil), do: pid

    parked = for h <- @hosts, w.hosts[h].parked != %{}, do: h
    w = retry(w)

    if waiting == [] and parked == [] and retries(w) == [] and w.net == [] do
      w
    else
      w =
        Enum.reduce(Enum.sort(waiting), w, fn pid, w ->
          case w.procs[pid] do
            %{role: :copy, c: c} ->
              copy_event(note(w, {:timer, pid}), pid, CopyProtocol.timeout(c)) |> check()

            %{role: :agent, src: %{}} ->
              source_event(note(w, {:timeout, pid}), pid, :timeout) |> check()

            _ ->
              w
          end
        end)

      w = Enum.reduce(parked, w, &ask_parked(&2, &1))
      quiesce(w, rounds - 1)
    end
  end

  defp drain(%{net: []} = w), do: w

  defp drain(%{net: net} = w) do
    w = %{w | net: []}
    w = Enum.reduce(Enum.reverse(net), w, fn m, w -> w |> deliver(m) |> check() end)
    drain(w)
  end

  # -- invariants ----------------------------------------------------------------------

  defp check(w) do
    running =
      for {_pid, %{role: :agent, host: h, env: env}} <- w.procs, alive_host?(w, h), do: env.id

    dup = running |> Enum.frequencies() |> Enum.find(fn {_, n} -> n > 1 end)
    if dup, do: violation(w, {:two_running_copies, elem(dup, 0)})
    w
  end

  defp check_final(w) do
    running = for({_pid, %{role: :agent, env: env}} <- w.procs, do: env.id) |> Enum.frequencies()

    for id <- w.known do
      n = Map.get(running, id, 0)
      excused = not w.persist and MapSet.member?(w.exposed, id)
      if n != 1 and not excused, do: violation(w, {:not_running_exactly_once, id, n})
    end

    # (A message to a clone's copy that never committed has no agent to reach.)
    for {n, %{agent: id, handled: k}} <- w.msgs,
        k != 1,
        MapSet.member?(w.known, id),
        not MapSet.member?(w.exposed, id),
        do: violation(w, {:message_not_handled_once, n, id, k})

    :ok
  end

  defp violation(w, what), do: raise(Violation, what: what, trace: Enum.reverse(w.trace))
end
