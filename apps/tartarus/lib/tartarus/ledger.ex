defmodule Tartarus.Ledger do
  @moduledoc """
  A host's ledger: the one ETS table (`:set`, public) where a host keeps what its processes
  must share without asking its server. This module is its only reader and writer: every
  other module (the host's server and warden, agents, the migration engine, the tools) goes
  through the functions below, never `:ets` on the table, and never builds a key
  (`apps/tartarus/test/tartarus/ledger_owner_test.exs` checks the sources). Internal: not part of the
  platform's documented API (`Tartarus`, `Tartarus.Agent`), and its records may change.

  The table is made by `new/1` for the host's warden (`Tartarus.Host.Warden`), which owns it:
  it outlives a crash of the host's server. The functions take the host's map (from
  `Tartarus.Host.local/1`, or an agent's `data.host`), except the admission memory's, which
  take the table (`Tartarus.Migration.Protocol.destination/1` holds it).

  ## Key kinds

  Each key kind, its record, who writes it (with which function) and who reads it.

  | key | record | written by | read by |
  |---|---|---|---|
  | `:neighbours` | `[host]` | `new/1`, `add_link/3`, `remove_link/2` (Host.Server: connect, disconnect) | `neighbours/1` (transport, signals, broadcasts, locator, status) |
  | `{:link, host}` | `%{latency_ms:, loss:}` | `add_link/3`, `remove_link/2` | `link/2` (Tartarus.Transport) |
  | `{:agent, pid}` | `id, name, module`: a resident agent | `register_resident/3`, `forget_resident/2` (agent process), `take_resident/2` (host server, for a dead one) | `residents/1`, `locate/2` |
  | `{:fwd, id}` | `:handoff, mig, source_pid`: an undecided hand-off (move or clone) of resident agent `id`, written before `prepare` leaves | `begin_handoff/3`; goes with `end_handoff/3` (abort), `put_pointer/7` (a move's commit: one write), `abort_pending/3`, `drop_handoffs/3` | `decision/4`, `abort_pending/3`, `departed?/2`, `handoffs/1` |
  | `{:fwd, id \\| name}` | `dest_host, at_us, {mig, copy} \\| :acked \\| :name, notify`: a forwarding pointer (an id's names its migration until the copy acknowledges; a name's never stands for a decision) | `put_pointer/7`, `acknowledge/4` (marks `:acked`); goes with `register_resident/3`, `forget_pointers/3`, `sweep_pointers/2` | `decision/4`, `locate/2`, `pointers/1`, `forwarding_pointers/1`, `abort_pending/3`, `departed?/2` |
  | `{:decision, mig}` | `{:committed, copy}`: a clone's commit until the clone acknowledges (and, after a restart with persistence, every journaled commit) | `decide/3`, `new/1`; goes with `acknowledge/4` | `decision/4`, `decisions/1` |
  | `{:arriving, id}` | `pid`: a paused copy here (destination) | `put_arriving/3` (Host.Arrivals, Host.Parked, Host.Agents.restore); goes with `drop_arriving/3` (the copy once resident; the host server when it is down) | `arriving?/2`, `arriving?/3`, `locate/2` |
  | `{:parked, {mig, copy}}` | `env, src, kind`: a parked in-doubt copy (destination) | `park/6`; goes with `unpark/3` (the host, dropping it; the copy revived from it, taking it) | `parked/1`, `fetch_parked/3` |
  | `:parked` | `n`: how many | `park/6`, `unpark/3` | `counter/2` (`:parked`) |
  | `{:count, name}` | `n`: e.g. `:dropped` (unexpected messages), `:buckets` | `count/2`; `swap_bucket/4` | `counted/2` |
  | `{:seen, mig}` | `what, seq`: admission's memory of a prepare (`:pending, nil` while one admission of it runs) | `seen_claim/2`, `seen_put/4`; goes with `seen_release/2` | `seen_fetch/2`, `seen_claim/2` |
  | `{:seen_order, seq}` | `mig`: its age, oldest forgotten first | `seen_put/4` | `seen_put/4` |
  | `:seen_next` | `seq`: the last sequence number taken | `seen_put/4` | `seen_put/4` |
  | `{:bucket, source_bin}` | `{scaled_tokens, at_ms}`: a source's admission rate bucket (the source as `term_to_binary`) (`Tartarus.Security.Admission`) | `swap_bucket/4` (Host.Arrivals) | `bucket/2`, `buckets/1` |
  | `{:proc, pid}` | `entry` (`%{id:, key:, restarts:, owner:, create:}`), or `{:uncounted, entry}` once the process ended by its own choice: an agent process the host watches | `put_proc/3` (Host.Agents); `uncount_proc/2` (the ending agent); goes with `drop_proc/2` (Host.Server on its `:DOWN`; the source as it leaves) | `procs/1` (a server that starts adopts them; the warden kills them), `proc?/2` |
  | `{:snapshot, key}` | `env`: the envelope agent process `key` starts and restarts from | `put_snapshot/3` (the agent once resident; Host.Agents for a restart or restore); goes with `drop_snapshot/2` | `fetch_snapshot/2` |
  | `{:creating, key}` | `from`: the creator of agent process `key`, until answered | `put_creator/3`; goes with `take_creator/2` (the agent, its creator or the host server: whoever answers) | `take_creator/2` |
  | `{:kill, pid}` | `true`: the host is killing `pid` (tells its exit signal from a forged one) | `mark_kill/2`; goes with `clear_kill/2` | `kill_marked?/2` (the agent) |
  | `{:exit_reason, pid}` | `reason`: an agent's crash reason, for a server that adopts it after it ended | `put_exit_reason/3` (the agent) | `take_exit_reason/2` (Host.Server) |
  | `{:watchdog, pid}` | `{tref, callback, ms, from}`: agent process `pid` is in a callback under its budget (timer `tref`) | `arm_watchdog/3`; goes with `disarm_watchdog/2` (the agent after the callback; Host.Warden when it overran; Host.Server when the process ended inside one) | `watchdog/2` (Host.Warden, through `Tartarus.Agent.Callbacks.overrun/3`) |
  | `{:overran, pid}` | `reason`: the watchdog stopped `pid` | `put_overrun/3` (Host.Warden) | `take_overrun/2` (Host.Server) |
  | `{:handling, id}` | `{pid, ref}`: the message a `:durable` agent is handling | `put_handling/3`; goes with `drop_handling/2` | `take_handling/2` (the restarted agent) |
  | `{:children, pid}` | `[pid]`: processes agent process `pid` started with `Tartarus.Agent.spawn_link/1` | `add_child/3` | `take_children/2` (the agent as it ends; the host when it was killed) |
  | `{:code_saved, module, md5}` | `true`: the module's code is in the journal (this run) | `code_saved/3` (Host.Persistence) | `code_saved?/3` |
  | `:server` | `pid`: the host's current server (`Tartarus.Host.server/1` reads it on the path of a hop and a create, without copying the host's map out of the registry) | `put_server/2` (Host.Server, at its start) | `server/1` |
  | `:stopping` | `true`: the host is stopping (no restarts, no creates) | `mark_stopping/1` (Host.Server, Host.Warden, Host.Supervisor); goes with `clear_stopping/1` | `stopping?/1` |

  Not in the table: the ring of recent hop times is an atomics array beside it (`host.hops`,
  `new_hop_ring/0`, `record_hop/2`, `hop_times/1`, `reset_hops/1`): two atomic operations a
  hop, no table write. And the host's tallies, updated by every create, hop and end, are an
  atomics array too (`host.tally`, `new_tally/0`), with no lock and no hashing: residents and
  visits (`register_resident/3`, `forget_resident/2`, `take_resident/2`; read by
  `counter/2`), the host's agent processes (`put_proc/3`, `drop_proc/2`, `uncount_proc/2`;
  `counted(host, :procs)`) and the admissions under way (`reserve_admission/1`,
  `release_admission/1`; `counted(host, :admitting)`). They live as long as the table (both
  the warden's).

  ## Who writes on the path of a hop

  The hot path of a migration does not go through the host's server: the agent writes its
  own hand-off record, pointer and residence (`begin_handoff/3`, `put_pointer/7`,
  `register_resident/3`, `forget_resident/2`); the process spawned for each prepare at the
  destination (the copy-to-be) writes admission's memory, counters and buckets and the
  arriving copy (`seen_claim/2`, `seen_put/4`, `reserve_admission/1`, `swap_bucket/4`,
  `put_arriving/3`, `put_proc/3`); the source's server answers
  queries and acknowledgements from the table (`decision/4`, `acknowledge/4`).
  """

  @typedoc "A host's map (`Tartarus.Host.local/1`): the ledger is its `:ledger`."
  @type host :: map()

  @slots 1024

  # -- the table -------------------------------------------------------------------------

  @doc """
  Makes a host's ledger (owned by the calling process, the host's warden): no neighbours, no
  residents, and the commits `decided` (`{mig, copy}`) an earlier run of the host journaled,
  as answers for destinations in doubt.
  """
  @spec new([{term(), term()}]) :: :ets.tid()
  def new(decided) do
    l =
      :ets.new(:tartarus_ledger, [:set, :public, read_concurrency: true, write_concurrency: true])

    :ets.insert(l, [{:neighbours, []}])
    :ets.insert(l, for({mig, copy} <- decided, do: {{:decision, mig}, {:committed, copy}}))
    l
  end

  # The tallies' slots (new_tally/0).
  @resident 1
  @visits 2
  @procs 3
  @admitting 4

  @doc "Makes a host's tallies (see \"Not in the table\" above), all zero."
  @spec new_tally() :: :atomics.atomics_ref()
  def new_tally, do: :atomics.new(4, signed: true)

  @doc "Records `pid` as the host's current server (written by the server as it starts)."
  @spec put_server(host(), pid()) :: true
  def put_server(%{ledger: l}, pid), do: :ets.insert(l, {:server, pid})

  @doc "The host's current server (`put_server/2`), or nil if none started yet."
  @spec server(host()) :: pid() | nil
  def server(%{ledger: l}) do
    case :ets.lookup(l, :server) do
      [{_, pid}] -> pid
      [] -> nil
    end
  end

  @doc """
  True if `table` is `host`'s ledger (for a tool that walks every table a host owns, such as
  the churn benchmark: it reads the ledger through `census/1`).
  """
  @spec table?(host(), term()) :: boolean()
  def table?(%{ledger: l}, table), do: l == table

  @doc """
  How many records of each key kind the ledger holds (the key's tag: `:fwd`, `:agent`,
  `:neighbours`...). One scan of the table: for tools, not for a hot path.
  """
  @spec census(host()) :: %{atom() => non_neg_integer()}
  def census(%{ledger: l}) do
    :ets.foldl(fn entry, acc -> Map.update(acc, kind(elem(entry, 0)), 1, &(&1 + 1)) end, %{}, l)
  end

  defp kind(key) when is_tuple(key), do: elem(key, 0)
  defp kind(key), do: key

  # -- the overlay -----------------------------------------------------------------------

  @doc """
  The host's neighbours. A host that stops takes its table with it; a message already on its
  way to the host (a signal the overlay relays, say) then finds no table: a stopped host has
  no neighbours, and its reader carries on.
  """
  @spec neighbours(host()) :: [term()]
  def neighbours(%{ledger: l}) do
    case :ets.lookup(l, :neighbours) do
      [{_, ns}] -> ns
      [] -> []
    end
  rescue
    ArgumentError -> []
  end

  @doc "The properties of the host's link to `dest` (nil if none)."
  @spec link(host(), term()) :: map() | nil
  def link(%{ledger: l}, dest) do
    case :ets.lookup(l, {:link, dest}) do
      [{_, props}] -> props
      [] -> nil
    end
  end

  @doc "A link to `other` with `props` (kept once among the neighbours, last if new)."
  @spec add_link(host(), term(), map()) :: true
  def add_link(%{ledger: l} = host, other, props) do
    ns = neighbours(host)
    :ets.insert(l, [{:neighbours, Enum.uniq(ns ++ [other])}, {{:link, other}, props}])
  end

  @doc "No link to `other` any more."
  @spec remove_link(host(), term()) :: true
  def remove_link(%{ledger: l} = host, other) do
    :ets.insert(l, {:neighbours, List.delete(neighbours(host), other)})
    :ets.delete(l, {:link, other})
  end

  # -- admission's memory ----------------------------------------------------------------

  @doc """
  What admission remembers of the prepare of `mig` (`Tartarus.Migration.Protocol.destination/1`'s
  `store:`): kept off the host server's heap (10,000 remembered prepares are about
  2.7 MB, which made every collection of that heap a long one), and it outlives a restart of
  the server. Takes the table, not the host. `:pending` while an admission of it runs
  (`seen_claim/2`).
  """
  @spec seen_fetch(:ets.tid(), term()) :: {:ok, term()} | :error
  def seen_fetch(ledger, mig) do
    case :ets.lookup(ledger, {:seen, mig}) do
      [{_, what, _seq}] -> {:ok, what}
      [] -> :error
    end
  end

  @doc "True while the host's ledger exists (its warden is up)."
  @spec exists?(host()) :: boolean()
  def exists?(%{ledger: l}), do: :ets.info(l) != :undefined

  @doc "The table admission's memory takes (`Tartarus.Migration.Protocol.destination/1`)."
  @spec admission_memory(host()) :: :ets.tid()
  def admission_memory(%{ledger: l}), do: l

  @doc """
  Claims the admission of `mig` for the caller (one process per prepare admits it, see
  `Tartarus.Host.Arrivals`), in one atomic insert: `:error` (nothing remembered: claimed,
  until `seen_put/4` or `seen_release/2`), `:busy` (another admission of `mig` runs) or
  `{:ok, what}` (remembered).
  """
  @spec seen_claim(:ets.tid(), term()) :: {:ok, term()} | :error | :busy
  def seen_claim(ledger, mig) do
    if :ets.insert_new(ledger, {{:seen, mig}, :pending, nil}) do
      :error
    else
      case seen_fetch(ledger, mig) do
        {:ok, :pending} -> :busy
        {:ok, what} -> {:ok, what}
        # Forgotten in between: claim again.
        :error -> seen_claim(ledger, mig)
      end
    end
  end

  @doc "Ends a claim of `mig` that made no copy (`seen_claim/2`): nothing is remembered."
  @spec seen_release(:ets.tid(), term()) :: :ok
  def seen_release(ledger, mig) do
    :ets.delete_object(ledger, {{:seen, mig}, :pending, nil})
    :ok
  end

  @doc """
  Remembers `what` for `mig`; past `max` migrations the oldest is forgotten. Safe from
  concurrent admissions: each new migration takes its own sequence number, and the one that
  takes `n` forgets the one of `n - max`.
  """
  @spec seen_put(:ets.tid(), term(), term(), pos_integer()) :: :ok
  def seen_put(ledger, mig, what, max) do
    case :ets.lookup(ledger, {:seen, mig}) do
      [{key, _, seq}] when is_integer(seq) ->
        :ets.insert(ledger, {key, what, seq})

      _new_or_claimed ->
        seq = :ets.update_counter(ledger, :seen_next, 1, {:seen_next, -1})
        :ets.insert(ledger, [{{:seen, mig}, what, seq}, {{:seen_order, seq}, mig}])
        if seq >= max, do: seen_forget(ledger, seq - max)
    end

    :ok
  end

  defp seen_forget(ledger, seq) do
    case :ets.take(ledger, {:seen_order, seq}) do
      [{_, mig}] -> :ets.match_delete(ledger, {{:seen, mig}, :_, seq})
      [] -> :ok
    end
  end

  # -- admission's counters and rate buckets (any process of the host admits) ---------------

  @doc """
  Reserves room for one arriving agent (`Tartarus.Host.Arrivals`, before it creates the
  copy) and returns how many agent processes the host holds besides it: its watched
  processes (`put_proc/3`) plus the reservations made before this one. Concurrent
  admissions each see a different count, so no two take the same last place. Ends with
  `put_proc/3` then `release_admission/1` (a copy), or `release_admission/1` alone.
  """
  @spec reserve_admission(host()) :: non_neg_integer()
  def reserve_admission(%{tally: t}) do
    before = :atomics.add_get(t, @admitting, 1) - 1
    :atomics.get(t, @procs) + before
  end

  @doc "Ends a reservation of `reserve_admission/1`."
  @spec release_admission(host()) :: integer()
  def release_admission(%{tally: t}), do: :atomics.sub_get(t, @admitting, 1)

  @doc "Source `source`'s admission bucket (`Tartarus.Security.Admission`), if it has one."
  @spec bucket(host(), term()) :: {:ok, term()} | :error
  def bucket(%{ledger: l}, source) do
    case :ets.lookup(l, bucket_key(source)) do
      [{_, b}] -> {:ok, b}
      [] -> :error
    end
  end

  @doc """
  Replaces source `source`'s bucket `old` (nil: none) by `new` (nil: none), only if it is
  still `old` (a compare-and-swap: concurrent admissions of one source take distinct
  tokens). True if it was replaced.
  """
  @spec swap_bucket(host(), term(), term(), term()) :: boolean()
  def swap_bucket(_host, _source, nil, nil), do: true

  def swap_bucket(%{ledger: l}, source, nil, new) do
    inserted = :ets.insert_new(l, {bucket_key(source), new})
    if inserted, do: :ets.update_counter(l, {:count, :buckets}, 1, {{:count, :buckets}, 0})
    inserted
  end

  def swap_bucket(%{ledger: l}, source, old, nil) do
    deleted = :ets.select_delete(l, [{{bucket_key(source), :"$1"}, is(old), [true]}]) == 1
    if deleted, do: :ets.update_counter(l, {:count, :buckets}, -1, {{:count, :buckets}, 0})
    deleted
  end

  def swap_bucket(%{ledger: l}, source, old, new) do
    key = bucket_key(source)
    :ets.select_replace(l, [{{key, :"$1"}, is(old), [{{{key}, {:const, new}}}]}]) == 1
  end

  # The source as a binary in the key: a match pattern that names the whole key (one
  # lookup, not a scan of the table) whatever term the source is.
  defp bucket_key(source), do: {:bucket, :erlang.term_to_binary(source)}
  defp is(value), do: [{:"=:=", :"$1", {:const, value}}]

  @doc "Every source's admission bucket, as a map (a scan)."
  @spec buckets(host()) :: map()
  def buckets(%{ledger: l}) do
    for [bin, b] <- :ets.match(l, {{:bucket, :"$1"}, :"$2"}),
        into: %{},
        do: {:erlang.binary_to_term(bin), b}
  end

  # -- residents -------------------------------------------------------------------------

  @doc """
  Agent `env` runs here as process `pid` (written by that process): in the node's agent
  table and the ledger, counted as a resident and a visit, and the forwarding pointers of an
  earlier visit (under its id and name) go. `{:error, _}` if the agent table refuses it.
  """
  @spec register_resident(host(), map(), pid()) :: :ok | {:error, term()}
  def register_resident(host, env, pid) do
    {name, _node} = host.ref

    case Tartarus.AgentTable.register(env.id, pid, name, env.name, env.module) do
      :ok ->
        :ets.insert(host.ledger, {{:agent, pid}, env.id, env.name, env.module})
        :ets.delete(host.ledger, {:fwd, env.id})
        if env.name, do: :ets.delete(host.ledger, {:fwd, env.name})
        :atomics.add(host.tally, @resident, 1)
        :atomics.add(host.tally, @visits, 1)
        :ok

      {:error, _} = error ->
        error
    end
  end

  @doc "Process `pid` is no longer resident here. True if it was."
  @spec forget_resident(host(), pid()) :: boolean()
  def forget_resident(host, pid) do
    case take_resident(host, pid) do
      {id, name, module} ->
        Tartarus.AgentTable.unregister(id, pid, elem(host.ref, 0), name, module)
        true

      nil ->
        false
    end
  end

  @doc """
  The host's server handles the end of resident process `pid` (its `:DOWN`): `pid` is no
  longer resident here, but the node's agent table keeps its entry, so that `locate/2` finds
  the agent in transition (`{:arriving, pid}`) while the server decides. A restart replaces
  the entry with the new process's; any other outcome removes it (`unregister_ended/3`).
  Returns `{id, name, module}`, or nil if `pid` was not resident.
  """
  @spec take_resident(host(), pid()) :: {binary(), term(), module()} | nil
  def take_resident(host, pid) do
    case :ets.take(host.ledger, {:agent, pid}) do
      [{_, id, name, module}] ->
        :atomics.sub(host.tally, @resident, 1)
        {id, name, module}

      [] ->
        nil
    end
  end

  @doc "The node's agent table forgets ended process `pid` (see `take_resident/2`)."
  @spec unregister_ended(host(), pid(), {binary(), term(), module()}) :: true
  def unregister_ended(host, pid, {id, name, module}),
    do: Tartarus.AgentTable.unregister(id, pid, elem(host.ref, 0), name, module)

  @doc """
  The node's agent table forgets agent `id`'s entry at this host if its process is dead: a
  restarted process that ended before it registered leaves no entry of its crashed
  predecessor behind (see `take_resident/2`).
  """
  @spec unregister_dead(host(), binary()) :: :ok
  def unregister_dead(host, id) do
    {name, _} = host.ref

    case Tartarus.AgentTable.entry(id) do
      {:ok, pid, ^name} when node(pid) == node() ->
        unless Process.alive?(pid), do: Tartarus.AgentTable.unregister_pid(id, pid)
        :ok

      _ ->
        :ok
    end
  end

  @doc "The resident agents, as `{id, name, module, pid}` (a scan of the table)."
  @spec residents(host()) :: [{binary(), term(), module(), pid()}]
  def residents(%{ledger: l}) do
    :ets.select(l, [
      {{{:agent, :"$1"}, :"$2", :"$3", :"$4"}, [], [{{:"$2", :"$3", :"$4", :"$1"}}]}
    ])
  end

  @doc """
  A count kept in the ledger: `:resident` (agents resident now), `:visits` (arrivals and
  creations so far), `:parked` (parked copies). One record, one update a hop.
  """
  @spec counter(host(), :resident | :visits | :parked) :: non_neg_integer()
  def counter(%{tally: t}, :resident), do: :atomics.get(t, @resident)
  def counter(%{tally: t}, :visits), do: :atomics.get(t, @visits)

  def counter(%{ledger: l}, :parked) do
    case :ets.lookup(l, :parked) do
      [{_, n}] -> n
      [] -> 0
    end
  end

  @doc "Counts one `name` (e.g. `:dropped`: an unexpected message a host process dropped)."
  @spec count(host(), atom()) :: integer()
  def count(%{ledger: l}, name),
    do: :ets.update_counter(l, {:count, name}, 1, {{:count, name}, 0})

  @doc "How many `name` were counted (`count/2`)."
  @spec counted(host(), atom()) :: non_neg_integer()
  def counted(%{tally: t}, :procs), do: :atomics.get(t, @procs)
  def counted(%{tally: t}, :admitting), do: :atomics.get(t, @admitting)

  def counted(%{ledger: l}, name) do
    case :ets.lookup(l, {:count, name}) do
      [{_, n}] -> n
      [] -> 0
    end
  end

  # -- hand-offs, pointers and decisions (source) -----------------------------------------

  @doc """
  Before `prepare` leaves: the migration `mig` of agent `id` is undecided (`decision/4` says
  `:unknown`), its source process the caller. Keyed by the agent's id: a kill or crash of the
  agent finds it, and a source process runs one hand-off at a time.
  """
  @spec begin_handoff(host(), binary(), term()) :: true
  def begin_handoff(host, id, mig),
    do: :ets.insert(host.ledger, {{:fwd, id}, :handoff, mig, self()})

  @doc "An abort (by the source process): the hand-off record goes with no commit written."
  @spec end_handoff(host(), binary(), term()) :: true
  def end_handoff(host, id, mig),
    do: :ets.delete_object(host.ledger, {{:fwd, id}, :handoff, mig, self()})

  @doc """
  A clone's commit (before its hand-off record goes). Returns false if one was already
  written (never: one writer).
  """
  @spec decide(host(), term(), {:committed, term()}) :: boolean()
  def decide(host, mig, decision), do: :ets.insert_new(host.ledger, {{:decision, mig}, decision})

  @doc """
  The agent committed the move `mig` (copy `copy`) to `dest`: its forwarding pointer, which
  names the commit for a destination that asks (see `decision/4`), replaces the hand-off
  record in one write (then the agent stops being resident: `forget_resident/2`). `notify`
  (a GenServer from, or nil) is who waits for the move to finish: a destination that learns
  of the commit by asking (the commit message was lost) answers it.
  """
  @spec put_pointer(host(), binary(), term(), term(), term(), term(), term()) :: term()
  def put_pointer(host, id, name, dest, mig, copy, notify) do
    now = Tartarus.Clock.system_time(:microsecond)
    :ets.insert(host.ledger, {{:fwd, id}, dest, now, {mig, copy}, notify})
    if name, do: :ets.insert(host.ledger, {{:fwd, name}, dest, now, :name, nil})
  end

  @doc """
  The agent `env` ended on this host (returned or stopped): the forwarding pointers it left
  on the hosts it visited lead nowhere now. Each of those hosts is told once (through its
  node's Tartarus.Host.Directory, without opening connections: a host on a node no longer
  connected keeps its pointer), and drops them (`forget_pointers/3`). Only the hosts its
  `visits` still remembers (the `max_visits` last) are told. Nothing else but `forward_ttl`
  reclaims the pointer of an agent that ended elsewhere.
  """
  @spec gone(host(), map()) :: :ok
  def gone(host, env) do
    for {{name, node} = h, _} <- env.visits, h != host.ref do
      :erlang.send(
        {Tartarus.Host.Directory, node},
        {:"$tartarus_gone", name, env.id, env.name},
        [:noconnect]
      )
    end

    :ok
  end

  @doc """
  Drops the forwarding pointers of agent `id` (and of its name) after it ended elsewhere.
  An agent that ended ran as its last committed copy, so no paused copy can still ask about a
  pointer's migration: a copy that does (a replay) is told aborted, which is right. An agent
  resident here has no pointer here.
  """
  @spec forget_pointers(host(), binary(), term()) :: :ok
  def forget_pointers(host, id, name) do
    :ets.delete(host.ledger, {:fwd, id})
    if name, do: :ets.delete(host.ledger, {:fwd, name})
    :ok
  end

  @doc """
  The answer to a paused copy `copy` of migration `mig` of agent `id` that asks this (source)
  host: `Tartarus.Migration.Protocol.answer/3` over what the ledger holds, read in the
  protocol's order (hand-off record first). `id` is the agent that left (for a clone, the
  clone's parent: `query_id/2`). One read decides a move (its hand-off record, then its
  pointer, under one key); a clone's commit is written before its hand-off record goes, so
  it is read second.
  """
  @spec decision(host(), term(), binary(), term()) :: term()
  def decision(host, mig, id, copy),
    do: Tartarus.Migration.Protocol.answer(decision_view(host, mig, id), mig, copy)

  @doc """
  What `decision/4` reads, in the protocol's order: `%{handoff?: boolean, decision: term,
  pointer: {mig, copy, notify} | nil}` (`Tartarus.Migration.Protocol.answer/3`'s view).
  """
  @spec decision_view(host(), term(), binary()) :: map()
  def decision_view(host, mig, id) do
    {handoff?, pointer} =
      case :ets.lookup(host.ledger, {:fwd, id}) do
        [{_, :handoff, ^mig, _pid}] -> {true, nil}
        [{_, _dest, _at, {m, c}, notify}] -> {false, {m, c, notify}}
        _ -> {false, nil}
      end

    decision =
      case :ets.lookup(host.ledger, {:decision, mig}) do
        [{_, d}] -> d
        [] -> nil
      end

    %{handoff?: handoff?, decision: decision, pointer: pointer}
  end

  @doc """
  The committed copy `copy` of `mig` (agent `id`) runs: its commit record is no longer
  needed. A clone's decision goes; a move's pointer stays for forwarding, marked `:acked`
  (sweepable).
  """
  @spec acknowledge(host(), term(), binary(), term()) :: :ok
  def acknowledge(host, mig, id, copy) do
    l = host.ledger

    case :ets.lookup(l, {:fwd, id}) do
      [{key, dest, at, {^mig, ^copy}, _notify}] -> :ets.insert(l, {key, dest, at, :acked, nil})
      # A clone's (or, after a restart with persistence, a journaled) commit.
      _ -> :ets.delete_object(l, {{:decision, mig}, {:committed, copy}})
    end

    :ok
  end

  @doc """
  After the agent `id` died or was killed: its undecided hand-offs are aborted (their records
  go; the process that could have committed them is dead). True if the agent is still ours to
  restart, false if it had committed a move (it lives on at the destination).

  A resident agent has no pointer here (its arrival deleted it), so a pointer under its id
  means it committed a move; a hand-off record means an undecided one (or a clone's).
  """
  @spec abort_pending(host(), binary(), pid() | nil) :: boolean()
  def abort_pending(host, id, _pid) do
    case :ets.lookup(host.ledger, {:fwd, id}) do
      [{_, :handoff, _mig, _p} = record] ->
        :ets.delete_object(host.ledger, record)
        true

      [{_, _dest, _at, _decision, _notify}] ->
        false

      [] ->
        true
    end
  end

  @doc "Drops the hand-off record of agent `id` by source process `pid`, which is gone."
  @spec drop_handoffs(host(), binary(), pid()) :: true
  def drop_handoffs(host, id, pid),
    do: :ets.match_delete(host.ledger, {{:fwd, id}, :handoff, :_, pid})

  @doc "True if agent `id` is leaving or left this host (a hand-off record or a pointer)."
  @spec departed?(host(), binary()) :: boolean()
  def departed?(host, id), do: :ets.member(host.ledger, {:fwd, id})

  @doc """
  The agent id a paused copy asks its source host about: the agent that left (a clone's
  parent for a clone).
  """
  @spec query_id(map(), :move | :clone) :: binary()
  def query_id(%{clone_of: parent}, :clone) when parent != nil, do: parent
  def query_id(env, _kind), do: env.id

  @doc """
  Drops forwarding pointers written before `cutoff_us` (system time) that no longer stand for
  a decision (acknowledged, or a name's): never one a paused copy may still need.
  """
  @spec sweep_pointers(host(), integer()) :: non_neg_integer()
  def sweep_pointers(%{ledger: l}, cutoff_us) do
    :ets.select_delete(l, [
      {{{:fwd, :_}, :_, :"$1", :"$2", :_}, [{:<, :"$1", cutoff_us}, {:is_atom, :"$2"}], [true]}
    ])
  end

  @doc """
  The forwarding pointers, as `{id or name, dest, state}`: `state` is `{mig, copy}` (a move
  whose copy has not acknowledged yet), `:acked` or `:name`. A scan: for status and tests.
  """
  @spec pointers(host()) :: [{term(), term(), {term(), term()} | :acked | :name}]
  def pointers(%{ledger: l}),
    do: :ets.select(l, [{{{:fwd, :"$1"}, :"$2", :_, :"$3", :_}, [], [{{:"$1", :"$2", :"$3"}}]}])

  @doc "The forwarding pointers of agent ids (not names), as `{id, dest}`."
  @spec forwarding_pointers(host()) :: [{binary(), term()}]
  def forwarding_pointers(host) do
    for {key, dest, _} <- pointers(host), is_binary(key) and byte_size(key) == 16, do: {key, dest}
  end

  @doc "The migrations with a hand-off record here (undecided). A scan."
  @spec handoffs(host()) :: [term()]
  def handoffs(%{ledger: l}),
    do: for([mig] <- :ets.match(l, {{:fwd, :_}, :handoff, :"$1", :_}), do: mig)

  @doc "The migrations with a commit record here (`decide/3`, until acknowledged). A scan."
  @spec decisions(host()) :: [term()]
  def decisions(%{ledger: l}), do: for([mig] <- :ets.match(l, {{:decision, :"$1"}, :_}), do: mig)

  # -- arriving and parked copies (destination) -------------------------------------------

  @doc "A paused copy `pid` of agent `id` is here (findable: messages to it wait)."
  @spec put_arriving(host(), binary(), pid()) :: true
  def put_arriving(host, id, pid), do: :ets.insert(host.ledger, {{:arriving, id}, pid})

  @doc "Copy `pid` of agent `id` is no longer arriving (it runs, or it is down)."
  @spec drop_arriving(host(), binary(), pid()) :: true
  def drop_arriving(host, id, pid), do: :ets.delete_object(host.ledger, {{:arriving, id}, pid})

  @doc "True if a copy of agent `id` is arriving here."
  @spec arriving?(host(), binary()) :: boolean()
  def arriving?(host, id), do: :ets.member(host.ledger, {:arriving, id})

  @doc "True if `pid` is the copy of agent `id` arriving here."
  @spec arriving?(host(), binary(), pid()) :: boolean()
  def arriving?(host, id, pid),
    do: :ets.lookup(host.ledger, {:arriving, id}) == [{{:arriving, id}, pid}]

  @doc """
  Keeps the record of the parked copy of migration `{mig, copy}` (and counts it). False if
  it was kept already.
  """
  @spec park(host(), term(), term(), map(), term(), atom()) :: boolean()
  def park(host, mig, copy, env, src, kind) do
    if :ets.insert_new(host.ledger, {{:parked, {mig, copy}}, env, src, kind}) do
      :ets.update_counter(host.ledger, :parked, 1, {:parked, 0})
      true
    else
      false
    end
  end

  @doc "The record of the parked copy of `{mig, copy}`: `{:ok, {env, src, kind}}` or `:error`."
  @spec fetch_parked(host(), term(), term()) :: {:ok, {map(), term(), atom()}} | :error
  def fetch_parked(host, mig, copy) do
    case :ets.lookup(host.ledger, {:parked, {mig, copy}}) do
      [{_, env, src, kind}] -> {:ok, {env, src, kind}}
      [] -> :error
    end
  end

  @doc "The parked copies, as `{mig, copy, env, src, kind}`. A scan."
  @spec parked(host()) :: [{term(), term(), map(), term(), atom()}]
  def parked(host) do
    for {{:parked, {mig, copy}}, env, src, kind} <-
          :ets.select(host.ledger, [{{{:parked, :_}, :_, :_, :_}, [], [:"$_"]}]),
        do: {mig, copy, env, src, kind}
  end

  @doc """
  The parked copy of `{mig, copy}` is dropped (by the host) or revived (taken by the copy
  revived from it, as it starts): its record goes. True if it was there.
  """
  @spec unpark(host(), term(), term()) :: boolean()
  def unpark(host, mig, copy) do
    # Taken once: of two copies revived from one record only one finds it (and the count
    # falls once).
    case :ets.take(host.ledger, {:parked, {mig, copy}}) do
      [_] ->
        :ets.update_counter(host.ledger, :parked, -1, {:parked, 0})
        true

      [] ->
        false
    end
  end

  # -- agent processes (the host's server and its agents) ----------------------------------

  @doc """
  Agent process `pid`, described by `entry`, is the host's: a server that starts after this
  one adopts it (`procs/1`), a stopping host kills it.
  """
  @spec put_proc(host(), pid(), map()) :: true
  def put_proc(%{ledger: l, tally: t}, pid, entry) do
    # Counted once per process (`counted(host, :procs)`: admission's count of agents).
    if :ets.insert_new(l, {{:proc, pid}, entry}),
      do: :atomics.add(t, @procs, 1),
      else: :ets.insert(l, {{:proc, pid}, entry})

    true
  end

  @doc "Agent process `pid` is down: no longer the host's."
  @spec drop_proc(host(), pid()) :: true
  def drop_proc(%{ledger: l, tally: t}, pid) do
    case :ets.take(l, {:proc, pid}) do
      [{_, {:uncounted, _}}] -> :ok
      [_] -> :atomics.sub(t, @procs, 1)
      [] -> :ok
    end

    true
  end

  @doc """
  Agent process `pid` ends by its own choice (it stopped, or returned its result): written
  by that process as it ends, it no longer counts among the host's agents
  (`counted(host, :procs)`, admission's count), while its record stays for the host's server
  to handle its `:DOWN` (however far behind that server is). Counted off once, whichever of
  this and `drop_proc/2` comes first.
  """
  @spec uncount_proc(host(), pid()) :: boolean()
  def uncount_proc(%{ledger: l, tally: t}, pid) do
    key = {:proc, pid}
    spec = [{{key, :"$1"}, [{:is_map, :"$1"}], [{{{key}, {{:uncounted, :"$1"}}}}]}]

    if :ets.select_replace(l, spec) == 1 do
      :atomics.sub(t, @procs, 1)
      true
    else
      false
    end
  end

  @doc "True if agent process `pid` is the host's."
  @spec proc?(host(), pid()) :: boolean()
  def proc?(host, pid), do: :ets.member(host.ledger, {:proc, pid})

  @doc "The host's agent processes, as `{pid, entry}`. A scan."
  @spec procs(host()) :: [{pid(), map()}]
  def procs(host) do
    for {pid, entry} <-
          :ets.select(host.ledger, [{{{:proc, :"$1"}, :"$2"}, [], [{{:"$1", :"$2"}}]}]) do
      case entry do
        {:uncounted, entry} -> {pid, entry}
        entry -> {pid, entry}
      end
    end
  end

  @doc "The envelope agent process `key` starts (and restarts) from."
  @spec put_snapshot(host(), reference(), map()) :: true
  def put_snapshot(host, key, env), do: :ets.insert(host.ledger, {{:snapshot, key}, env})

  @doc """
  The snapshot of agent process `key`: `{:ok, env}` or `:error`. Read only when needed:
  copying it on every departure would fill the reader's heap with every passing agent's state.
  """
  @spec fetch_snapshot(host(), reference()) :: {:ok, map()} | :error
  def fetch_snapshot(host, key) do
    case :ets.lookup(host.ledger, {:snapshot, key}) do
      [{_, env}] -> {:ok, env}
      [] -> :error
    end
  end

  @doc "The snapshot of agent process `key` goes."
  @spec drop_snapshot(host(), reference()) :: true
  def drop_snapshot(host, key), do: :ets.delete(host.ledger, {:snapshot, key})

  @doc "`from` waits for agent process `key`'s creation (answered once, by `take_creator/2`'s taker)."
  @spec put_creator(host(), reference(), term()) :: true
  def put_creator(host, key, from), do: :ets.insert(host.ledger, {{:creating, key}, from})

  @doc """
  Takes the creator waiting for agent process `key`: `{:ok, from}` for the one taker that
  answers it, `:error` if it was answered (or never waited).
  """
  @spec take_creator(host(), reference()) :: {:ok, term()} | :error
  def take_creator(host, key) do
    case :ets.take(host.ledger, {:creating, key}) do
      [{_, from}] -> {:ok, from}
      [] -> :error
    end
  end

  @doc "The host kills agent process `pid` (its exit signal is real)."
  @spec mark_kill(host(), pid()) :: true
  def mark_kill(host, pid), do: :ets.insert(host.ledger, {{:kill, pid}, true})

  @doc "The killed agent process `pid` is down."
  @spec clear_kill(host(), pid()) :: true
  def clear_kill(host, pid), do: :ets.delete(host.ledger, {:kill, pid})

  @doc "True if the host is killing agent process `pid`."
  @spec kill_marked?(host(), pid()) :: boolean()
  def kill_marked?(host, pid), do: :ets.member(host.ledger, {:kill, pid})

  @doc "Agent process `pid` crashed with `reason` (for a server that adopts it only after)."
  @spec put_exit_reason(host(), pid(), term()) :: true
  def put_exit_reason(host, pid, reason),
    do: :ets.insert(host.ledger, {{:exit_reason, pid}, reason})

  @doc "Takes the crash reason agent process `pid` left: `{:ok, reason}` or `:error`."
  @spec take_exit_reason(host(), pid()) :: {:ok, term()} | :error
  def take_exit_reason(host, pid), do: take(host, {:exit_reason, pid})

  @doc """
  Agent process `pid` runs a callback under the watchdog: `dog` is `{tref, callback, ms,
  from}` (its budget's timer, the callback, the budget, the requester or nil). Written by
  the agent before the callback, replacing any entry before it (`Tartarus.Agent.Callbacks`).
  """
  @spec arm_watchdog(host(), pid(), {reference(), atom(), pos_integer(), term()}) :: true
  def arm_watchdog(host, pid, dog), do: :ets.insert(host.ledger, {{:watchdog, pid}, dog})

  @doc "Agent process `pid` is out of its callback (or ended): its watchdog entry goes."
  @spec disarm_watchdog(host(), pid()) :: true
  def disarm_watchdog(host, pid), do: :ets.delete(host.ledger, {:watchdog, pid})

  @doc """
  The watchdog entry of agent process `pid` (`arm_watchdog/3`), or nil if it is in no
  callback under a budget: what the host's watchdog reads when a budget's timer fires.
  """
  @spec watchdog(host(), pid()) :: {reference(), atom(), pos_integer(), term()} | nil
  def watchdog(host, pid) do
    case :ets.lookup(host.ledger, {:watchdog, pid}) do
      [{_, dog}] -> dog
      [] -> nil
    end
  end

  @doc "The watchdog stopped agent process `pid` for `reason`."
  @spec put_overrun(host(), pid(), term()) :: true
  def put_overrun(host, pid, reason), do: :ets.insert(host.ledger, {{:overran, pid}, reason})

  @doc "Takes the watchdog's reason for agent process `pid`: `{:ok, reason}` or `:error`."
  @spec take_overrun(host(), pid()) :: {:ok, term()} | :error
  def take_overrun(host, pid), do: take(host, {:overran, pid})

  @doc "A `:durable` agent `id` is handling the message from `from` (`{pid, ref}`)."
  @spec put_handling(host(), binary(), {pid(), reference()}) :: true
  def put_handling(host, id, from), do: :ets.insert(host.ledger, {{:handling, id}, from})

  @doc "Agent `id` handled its message."
  @spec drop_handling(host(), binary()) :: true
  def drop_handling(host, id), do: :ets.delete(host.ledger, {:handling, id})

  @doc "Takes the message agent `id` was handling when it crashed: `{:ok, from}` or `:error`."
  @spec take_handling(host(), binary()) :: {:ok, {pid(), reference()}} | :error
  def take_handling(host, id), do: take(host, {:handling, id})

  @doc "Agent process `agent` started `child` (kept with its other live children)."
  @spec add_child(host(), pid(), pid()) :: true
  def add_child(host, agent, child) do
    kids =
      case :ets.lookup(host.ledger, {:children, agent}) do
        [{_, kids}] -> Enum.filter(kids, &Process.alive?/1)
        [] -> []
      end

    :ets.insert(host.ledger, {{:children, agent}, [child | kids]})
  end

  @doc "Takes the processes agent process `agent` started (`[]` if none)."
  @spec take_children(host(), pid()) :: [pid()]
  def take_children(host, agent) do
    case take(host, {:children, agent}) do
      {:ok, kids} -> kids
      :error -> []
    end
  end

  @doc "True if `module` (its code `md5`) was saved in the host's journal in this run."
  @spec code_saved?(host(), module(), binary()) :: boolean()
  def code_saved?(host, module, md5), do: :ets.member(host.ledger, {:code_saved, module, md5})

  @doc "`module` (its code `md5`) is saved in the host's journal."
  @spec code_saved(host(), module(), binary()) :: true
  def code_saved(host, module, md5),
    do: :ets.insert(host.ledger, {{:code_saved, module, md5}, true})

  @doc "The host is stopping: its agents' deaths are not crashes, and creates are refused."
  @spec mark_stopping(host()) :: true
  def mark_stopping(host), do: :ets.insert(host.ledger, {:stopping, true})

  @doc "The host runs again (a restarted server or keeper)."
  @spec clear_stopping(host()) :: true
  def clear_stopping(host), do: :ets.delete(host.ledger, :stopping)

  @doc "True if the host is stopping."
  @spec stopping?(host()) :: boolean()
  def stopping?(host), do: :ets.member(host.ledger, :stopping)

  defp take(host, key) do
    case :ets.take(host.ledger, key) do
      [{_, value}] -> {:ok, value}
      [] -> :error
    end
  end

  # -- hop times (beside the table) ------------------------------------------------------

  @doc """
  A ring of recent hop times: an atomics array (slot 1: the sequence; slots 2..: the times
  plus one, 0 for an empty slot): two atomic operations a hop, no table write.
  """
  @spec new_hop_ring() :: :atomics.atomics_ref()
  def new_hop_ring, do: :atomics.new(@slots + 1, [])

  @doc "Records one hop of `hop_us` microseconds (the last #{@slots} are kept)."
  @spec record_hop(host(), non_neg_integer()) :: :ok
  def record_hop(%{hops: ring}, hop_us) do
    seq = :atomics.add_get(ring, 1, 1)
    :atomics.put(ring, 2 + rem(seq, @slots), hop_us + 1)
  end

  @doc "The recent hop times (microseconds), in no order."
  @spec hop_times(host()) :: [non_neg_integer()]
  def hop_times(%{hops: ring}) do
    # Only the slots written so far: a host that saw 5 hops costs 5 reads, not @slots.
    case :atomics.get(ring, 1) do
      0 ->
        []

      seq when seq < @slots ->
        for k <- 1..seq, (t = :atomics.get(ring, 2 + rem(k, @slots))) > 0, do: t - 1

      _ ->
        for i <- 2..(@slots + 1), (t = :atomics.get(ring, i)) > 0, do: t - 1
    end
  end

  @doc "Empties the ring (benchmarks measure a phase at a time)."
  @spec reset_hops(host()) :: :ok
  def reset_hops(%{hops: ring}) do
    for i <- 1..(@slots + 1), do: :atomics.put(ring, i, 0)
    :ok
  end

  # -- where an agent is -----------------------------------------------------------------

  @doc """
  Where is `agent` (an id or a name) as far as this host knows: `{:here, pid, id}`,
  `{:arriving, pid}`, `{:moved, dest}` or `:not_found`. `{:arriving, pid}` also stands for a
  resident whose process `pid` ended while this host's server decides whether to restart it
  (`take_resident/2`): a caller tries again, as for an arriving copy.
  """
  @spec locate(host(), term()) ::
          {:here, pid(), term()} | {:arriving, pid()} | {:moved, term()} | :not_found
  def locate(host, agent) do
    {name, _} = host.ref

    case Tartarus.AgentTable.lookup(agent) do
      {:ok, pid, ^name} -> {:here, pid, agent}
      _ -> locate_elsewhere(host, agent)
    end
  end

  # A resident whose process ended and whose host has not yet restarted or removed it (see
  # take_resident/2): in transition, like an arriving copy; a reader tries again.
  defp ending(host, agent) do
    {name, _} = host.ref

    case Tartarus.AgentTable.entry(agent) do
      {:ok, pid, ^name} -> [{{:arriving, agent}, pid}]
      _ -> []
    end
  end

  # Not resident here: arriving, or gone on (a forwarding pointer). An arriving agent
  # registers before it drops its `arriving` entry (and the forwarding pointer of its
  # previous visit), and a departing one writes its pointer before it leaves the table: a
  # reader that missed it in the table and then found neither entry looks in the table and
  # here once more. (An agent that hops at every arrival can come and go between two of the
  # reader's looks: then the pointer it left is there now.)
  defp locate_elsewhere(host, agent, again \\ true) do
    with [] <- :ets.lookup(host.ledger, {:arriving, agent}),
         [] <- pointer(host, agent),
         [] <- ending(host, agent) do
      if again, do: just_arrived(host, agent), else: locate_by_name(host, agent)
    else
      [{_, pid}] -> {:arriving, pid}
      [{_, dest, _, _, _}] -> {:moved, dest}
    end
  end

  # A forwarding pointer (not a hand-off record, which is kept under the same key).
  defp pointer(host, agent) do
    case :ets.lookup(host.ledger, {:fwd, agent}) do
      [{_, _, _, _, _}] = found -> found
      _ -> []
    end
  end

  defp just_arrived(host, agent) do
    {name, _} = host.ref

    case Tartarus.AgentTable.lookup(agent) do
      {:ok, pid, ^name} -> {:here, pid, agent}
      _ -> locate_elsewhere(host, agent, false)
    end
  end

  defp locate_by_name(host, agent) do
    # A select with the name as a constant: a name such as :_ or :"$1" is not a pattern.
    spec = [
      {{{:agent, :"$1"}, :"$2", :"$3", :_}, [{:"=:=", :"$3", {:const, agent}}],
       [{{:"$1", :"$2"}}]}
    ]

    case :ets.select(host.ledger, spec, 1) do
      {[{pid, id} | _], _} -> {:here, pid, id}
      _ -> :not_found
    end
  end
end
