defmodule Tartarus.Signal do
  @moduledoc """
  Signal fields on the overlay: danger signals, pheromones, anything a host diffuses to the
  hosts around it and agents climb.

  A host **emits** a named signal with a strength, a span in hops and a lifetime
  (`Tartarus.emit_signal/4`, or `Tartarus.Agent.emit_signal/3` from an agent). The signal
  travels hop by hop: the emitting host sends it to its neighbours, and each host that
  takes it relays it to its own neighbours (except the one it came from) while span
  remains. Every hop is a message between hosts (the node-level process
  `Tartarus.Overlay` of the receiving host's node handles it), so fields spread across
  BEAM nodes like agents do.

  ## The laws

  At `h` hops from its source a signal of strength `s`, span `S` and lifetime `L` has
  the base strength `decay(s, h)` and the lifetime `lifetime_decay(L, h)`, with one of
  these laws (option `:decay`, and `:lifetime_decay` for the lifetime):

    * `:linear` (the default decay, thesis Eqs. 6.2 and 6.4: `ΔSg = Sg_max / l_span`):
      `s * (1 - h / S)`; it reaches 0 at `h = S`, so hosts up to `S - 1` hops away carry
      it (with span 0 only the emitter);
    * `{:linear, delta}`: `max(s - h * delta, 0)`;
    * `{:exponential, f}` (`0 < f <= 1`): `s * f^h`;
    * `:none` (the default lifetime decay): `s`.

  Hosts farther than `S` hops never receive the signal (the **span cut-off**), whatever
  the law. The signal **evaporates** with time: an age-`t` contribution with base strength
  `b` and lifetime `l` is worth (option `:evaporation`):

    * `:linear` (the default): `b * (1 - t / l)` until `t = l`;
    * `:step`: `b` until `t = l`;
    * `{:exponential, half_life_ms}`: `b * 2^(-t / half_life)` until `t = l`;

  and 0 afterwards (a lifetime of `:infinity` never evaporates). Nothing runs to evaporate
  signals: values are computed from timestamps when they are read. Ages travel in the
  messages (not clock readings), so nodes need no common clock.

  ## What a host keeps

  Per signal name, a host keeps one **contribution per source** (the emitting host): the
  strongest now (a contribution arriving by a shorter path, or a fresher emission,
  replaces a weaker one; a weaker one is dropped and not relayed, which also ends the
  flood). A host's **value** of a signal combines its contributions: the maximum by
  default (the field then points at the nearest strong source), or their sum with
  `combine: :sum`. A host also remembers the value each neighbour announced when it
  relayed the signal: that is what the `{:gradient, name}` strategy climbs (it moves to
  the neighbour with the highest value, see `Tartarus.Strategy`).

  An emission may carry `:data` (any plain term, e.g. the feature vector of the problem
  that caused a danger signal): `contributions/2` returns it with each contribution.

  ## Storage and cost

  One process per node (`Tartarus.Overlay`) owns an ETS table holding the fields of every
  host of that node (one entry per host and signal name), and handles the signal messages;
  reads (`value/3`, `contributions/2`, the gradient strategy) go to ETS directly without
  a message. One process, not one per host, because a node may run thousands of emulated
  hosts and a signal touches many of them at once; and not the host's store table, so the
  fields do not mix with application data and the host server is not involved. The fields
  of a host are dropped when it stops.

  ## Watching

  A process can **watch** a signal at a host (`watch/3`, or `Tartarus.Agent.watch_signal/1`
  from an agent): it then receives `{:tartarus_signal, host, name}` each time the host
  takes a new contribution to that signal (the field arrives, or a stronger or fresher
  emission replaces one), so it can wait for a field without polling. The message says
  only that something changed: read the field (`value/3`, `neighbour_values/3`) after it.
  Watch first and read after, so a field that arrives in between is not missed. (Fields are
  kept by `{host, name}` in an ordered table, which compares names with `==`: `1` and `1.0`
  are one signal there, but a watch of `1` is not told of `1.0`; use names that do not
  differ only so.) A watch
  ends with `unwatch/3` or when the process exits (an agent's watches end when it leaves
  the host).

  Every relay is counted for the sending host: `:signal_messages` and `:signal_bytes`
  (`:erlang.external_size/1` of each message), and each emission as `:signals` (see
  `Tartarus.Events`, event types `:signal` and `:signal_relay`).

  ## Example

      iex> {:ok, _} = Tartarus.start_host(:sig_a)
      iex> {:ok, _} = Tartarus.start_host(:sig_b, neighbours: [:sig_a])
      iex> {:ok, _} = Tartarus.start_host(:sig_c, neighbours: [:sig_b])
      iex> Tartarus.emit_signal(:sig_a, :danger, 100, span: 2, data: %{problem: 7})
      :ok
      iex> Tartarus.Signal.settle()
      :ok
      iex> for h <- [:sig_a, :sig_b, :sig_c], do: Tartarus.signal(h, :danger)
      [100.0, 50.0, 0.0]
      iex> [%{hops: 1, data: %{problem: 7}}] = Tartarus.Signal.contributions(:sig_b, :danger)
      iex> Tartarus.Signal.neighbour_values(:sig_b, :danger)
      %{{:sig_a, node()} => 100.0}
      iex> Enum.each([:sig_a, :sig_b, :sig_c], &Tartarus.stop_host/1)
      :ok

  (Without a `:lifetime` the signal does not evaporate; with one, reads made later give
  less.)
  """

  alias Tartarus.{Clock, Events, Host, Ledger, Options}

  @typedoc "A signal's name: any plain term."
  @type name :: term()

  @typedoc "A decay law over hops (see the moduledoc)."
  @type decay :: :linear | {:linear, number()} | {:exponential, number()} | :none

  @typedoc "An evaporation law over time (see the moduledoc)."
  @type evaporation :: :linear | :step | {:exponential, pos_integer()}

  @typedoc """
  What travels with a signal: the emission's parameters (strength, span, lifetime in ms,
  laws, data) and, once emitted, its `:id`.
  """
  @type emission :: %{
          strength: number(),
          span: non_neg_integer(),
          lifetime: pos_integer() | :infinity,
          decay: decay(),
          lifetime_decay: decay(),
          evaporation: evaporation(),
          data: term()
        }

  @typedoc """
  A contribution as a host keeps it: the source and the emission's id, hops from the
  source, the base strength at those hops, when it was born (this node's monotonic µs),
  its lifetime here (µs) and laws.
  """
  @type contribution :: %{
          source: Tartarus.host(),
          emission: term(),
          hops: non_neg_integer(),
          base: float(),
          born: integer(),
          life: pos_integer() | :infinity,
          evaporation: evaporation(),
          data: term()
        }

  @schema [
    span: [type: :non_neg_integer, default: 2, doc: "how many hops the signal travels"],
    lifetime: [
      type: :pos_integer_or_infinity,
      default: :infinity,
      doc: "ms the signal lives at its source"
    ],
    decay: [type: :any, default: :linear, doc: "decay of the strength with hops"],
    lifetime_decay: [type: :any, default: :none, doc: "decay of the lifetime with hops"],
    evaporation: [type: :any, default: :linear, doc: "how the signal fades over its lifetime"],
    data: [type: :any, default: nil, doc: "a plain term carried with the signal"]
  ]

  @doc false
  def schema, do: @schema

  @decay_doc ":linear, {:linear, delta >= 0}, {:exponential, f} with 0 < f <= 1, or :none"
  @evap_doc ":linear, :step or {:exponential, half_life_ms}"

  @doc """
  Validates the options of an emission of strength `strength`; returns the emission.

      iex> {:ok, e} = Tartarus.Signal.emission(100, span: 3)
      iex> {e.strength, e.span, e.lifetime, e.decay}
      {100, 3, :infinity, :linear}
      iex> Tartarus.Signal.emission(100, decay: {:exponential, 2})
      {:error, "invalid options given to Tartarus.emit_signal/4 for key :decay: expected :linear, {:linear, delta >= 0}, {:exponential, f} with 0 < f <= 1, or :none, got: {:exponential, 2}"}
  """
  @spec emission(number(), keyword()) :: {:ok, emission()} | {:error, String.t()}
  def emission(strength, opts) do
    where = "Tartarus.emit_signal/4"

    with :ok <- check_strength(strength, where),
         {:ok, opts} <- Options.validate(opts, @schema, where),
         :ok <- check_law(opts, :decay, &decay_law?/1, @decay_doc, where),
         :ok <- check_law(opts, :lifetime_decay, &decay_law?/1, @decay_doc, where),
         :ok <- check_law(opts, :evaporation, &evaporation_law?/1, @evap_doc, where),
         :ok <- check_portable(opts[:data], where) do
      {:ok, opts |> Map.new() |> Map.put(:strength, strength)}
    end
  end

  defp check_strength(s, _where) when is_number(s) and s >= 0, do: :ok

  defp check_strength(s, where),
    do: {:error, "invalid strength given to #{where}: expected a number >= 0, got: #{inspect(s)}"}

  defp check_law(opts, key, valid?, doc, where) do
    if valid?.(opts[key]),
      do: :ok,
      else:
        {:error,
         "invalid options given to #{where} for key #{inspect(key)}: expected #{doc}, got: #{inspect(opts[key])}"}
  end

  defp check_portable(data, where) do
    case Tartarus.Envelope.portable?(data) do
      :ok ->
        :ok

      {:error, _} ->
        {:error,
         "invalid options given to #{where} for key :data: expected plain data, got: #{inspect(data)}"}
    end
  end

  defp decay_law?(:linear), do: true
  defp decay_law?(:none), do: true
  defp decay_law?({:linear, d}) when is_number(d) and d >= 0, do: true
  defp decay_law?({:exponential, f}) when is_number(f) and f > 0 and f <= 1, do: true
  defp decay_law?(_), do: false

  defp evaporation_law?(:linear), do: true
  defp evaporation_law?(:step), do: true
  defp evaporation_law?({:exponential, h}) when is_integer(h) and h > 0, do: true
  defp evaporation_law?(_), do: false

  # -- the laws (pure) ---------------------------------------------------------------

  @doc """
  The value of `x` (a strength or a lifetime) at `hops` hops with decay law `law` and span
  `span` (see the moduledoc). A lifetime of `:infinity` stays infinite.

      iex> for h <- 0..2, do: Tartarus.Signal.decay(:linear, 100, h, 2)
      [100.0, 50.0, 0.0]
      iex> Tartarus.Signal.decay({:exponential, 0.5}, 100, 3, 5)
      12.5
      iex> Tartarus.Signal.decay({:linear, 30}, 100, 4, 5)
      0.0
      iex> Tartarus.Signal.decay(:none, 7, 3, 5)
      7.0
  """
  @spec decay(decay(), number() | :infinity, non_neg_integer(), non_neg_integer()) ::
          float() | :infinity
  def decay(_law, :infinity, _hops, _span), do: :infinity
  def decay(:none, x, _hops, _span), do: x * 1.0
  def decay(_law, x, 0, _span), do: x * 1.0
  def decay(:linear, x, h, span) when span > 0, do: max(x * (1 - h / span), 0.0)
  def decay(:linear, _x, _h, _span), do: 0.0
  def decay({:linear, d}, x, h, _span), do: max(x - h * d, 0.0) * 1.0
  def decay({:exponential, f}, x, h, _span), do: x * :math.pow(f, h)

  @doc """
  The value of a contribution of base strength `base` and lifetime `life_ms` at age
  `age_ms` under evaporation law `law` (see the moduledoc).

      iex> Tartarus.Signal.evaporate(:linear, 100, 250, 1_000)
      75.0
      iex> Tartarus.Signal.evaporate(:step, 100, 999, 1_000)
      100.0
      iex> Tartarus.Signal.evaporate(:step, 100, 1_000, 1_000)
      0.0
      iex> Tartarus.Signal.evaporate({:exponential, 100}, 100, 200, 1_000)
      25.0
      iex> Tartarus.Signal.evaporate(:linear, 100, 10_000_000, :infinity)
      100.0
  """
  @spec evaporate(evaporation(), number(), number(), number() | :infinity) :: float()
  def evaporate(_law, base, _age, :infinity), do: base * 1.0
  def evaporate(_law, _base, age, life) when age >= life, do: 0.0
  def evaporate(:linear, base, age, life), do: base * (1 - max(age, 0) / life)
  def evaporate(:step, base, _age, _life), do: base * 1.0

  def evaporate({:exponential, half}, base, age, _life),
    do: base * :math.pow(2, -max(age, 0) / half)

  @doc """
  A contribution of emission `e` from `source` at `hops` hops, born at `born` (µs, in the
  time base of `now` used with `worth/2`).

      iex> {:ok, e} = Tartarus.Signal.emission(100, span: 4, lifetime: 1_000)
      iex> c = Tartarus.Signal.contribution(e, {:a, :n}, 1, 0)
      iex> {c.base, c.life}
      {75.0, 1000000}
      iex> Tartarus.Signal.worth(c, 500_000)
      37.5
  """
  @spec contribution(emission(), Tartarus.host(), non_neg_integer(), integer()) :: contribution()
  def contribution(e, source, hops, born) do
    life =
      case decay(e.lifetime_decay, e.lifetime, hops, e.span) do
        :infinity -> :infinity
        ms -> round(ms * 1000)
      end

    %{
      source: source,
      emission: Map.get(e, :id),
      hops: hops,
      base: decay(e.decay, e.strength, hops, e.span),
      born: born,
      life: life,
      evaporation: e.evaporation,
      data: e.data
    }
  end

  @doc "What contribution `c` is worth at time `now` (µs, same base as `c.born`)."
  @spec worth(contribution(), integer()) :: float()
  def worth(%{life: :infinity, base: b}, _now), do: b * 1.0
  def worth(%{life: life}, _now) when life <= 0, do: 0.0
  def worth(c, now), do: evaporate(c.evaporation, c.base, (now - c.born) / 1000, c.life / 1000)

  @doc """
  True if contribution `new` should replace `old` at time `now`. Of one emission (arriving
  by several paths) the one from fewer hops wins; of different emissions of a source (a
  re-emission) the one worth more now, or as much and lasting longer.
  """
  @spec better?(contribution(), contribution() | nil, integer()) :: boolean()
  def better?(_new, nil, _now), do: true

  # The same emission by another path: only a shorter path counts (transit time must not
  # make a longer path look fresher).
  def better?(%{emission: id, hops: h}, %{emission: id, hops: old_h}, _now) when id != nil,
    do: h < old_h

  def better?(new, old, now) do
    wn = worth(new, now)
    wo = worth(old, now)
    wn > wo or (wn == wo and wn > 0 and expiry(new) > expiry(old))
  end

  defp expiry(%{life: :infinity}), do: :infinity
  defp expiry(%{born: b, life: l}), do: b + l

  @doc """
  Combines values: `:max` (the default) or `:sum`.

      iex> Tartarus.Signal.combine([1.0, 3.0, 2.0], :max)
      3.0
      iex> Tartarus.Signal.combine([1.0, 3.0, 2.0], :sum)
      6.0
      iex> Tartarus.Signal.combine([], :max)
      0.0
  """
  @spec combine([float()], :max | :sum) :: float()
  def combine([], _how), do: 0.0
  def combine(values, :max), do: Enum.max(values) * 1.0
  def combine(values, :sum), do: Enum.sum(values) * 1.0

  # -- reading -----------------------------------------------------------------------

  @doc """
  The value of signal `name` at `host` now (0.0 where there is none). Options:
  `combine: :max | :sum` (how contributions of several sources add up, `:max` by default).
  Reads ETS directly for a host on this node; asks the host's node otherwise.
  """
  @spec value(Tartarus.host_ref(), name(), keyword()) :: float() | {:error, term()}
  def value(host, name, opts \\ []) do
    on_node(host, :local_value, [name, opts])
  end

  @doc false
  def local_value({host_name, _}, name, opts) do
    now = now_us()

    own(host_name, name)
    |> Enum.map(fn {_src, c} -> worth(c, now) end)
    |> Enum.filter(&(&1 > 0))
    |> combine(Keyword.get(opts, :combine, :max))
  end

  @doc """
  The live contributions to signal `name` at `host`: one map per source with `:source`,
  `:hops`, `:value` (now) and `:data`, strongest first.
  """
  @spec contributions(Tartarus.host_ref(), name()) :: [map()] | {:error, term()}
  def contributions(host, name), do: on_node(host, :local_contributions, [name])

  @doc false
  def local_contributions({host_name, _}, name) do
    now = now_us()

    own(host_name, name)
    |> Enum.map(fn {src, c} ->
      %{source: src, hops: c.hops, value: worth(c, now), data: c.data}
    end)
    |> Enum.filter(&(&1.value > 0))
    |> Enum.sort_by(&(-&1.value))
  end

  @doc """
  The values of signal `name` at the neighbours of `host`, as `host` knows them (from the
  relays it received): `%{neighbour => value}` for the current neighbours with a value
  above 0. Options: `combine:` as in `value/3`.
  """
  @spec neighbour_values(Tartarus.host_ref(), name(), keyword()) ::
          %{Tartarus.host() => float()} | {:error, term()}
  def neighbour_values(host, name, opts \\ []),
    do: on_node(host, :local_neighbour_values, [name, opts])

  @doc false
  def local_neighbour_values({host_name, _} = host, name, opts) do
    with {:ok, info} <- Host.local(host) do
      gradient(info, host_name, name, opts)
    end
  end

  @doc false
  # For the {:gradient, name} strategy: the neighbours' values of `name` as `host` (a
  # host's info map) knows them, and the host-store entry {:gradient, name} (a map
  # neighbour => value written by hand) on top of them.
  @spec strategy_gradient(map(), name()) :: %{Tartarus.host() => number()}
  def strategy_gradient(%{ref: {host_name, _}} = host, name) do
    field = gradient(host, host_name, name, [])

    case :ets.lookup(host.store, {:gradient, name}) do
      [{_, manual}] when is_map(manual) -> Map.merge(field, manual)
      _ -> field
    end
  end

  defp gradient(info, host_name, name, opts) do
    now = now_us()
    how = Keyword.get(opts, :combine, :max)

    info
    |> Ledger.neighbours()
    |> Enum.flat_map(fn n ->
      values =
        host_name
        |> nbr(name, n)
        |> Enum.map(fn {_src, c} -> worth(c, now) end)
        |> Enum.filter(&(&1 > 0))

      if values == [], do: [], else: [{n, combine(values, how)}]
    end)
    |> Map.new()
  end

  defp own(host_name, name) do
    case lookup(host_name, name) do
      %{own: own} -> Map.to_list(own)
      _ -> []
    end
  end

  defp nbr(host_name, name, n) do
    case lookup(host_name, name) do
      %{nbrs: %{^n => by_source}} -> Map.to_list(by_source)
      _ -> []
    end
  end

  defp lookup(host_name, name) do
    case :ets.lookup(:tartarus_signals, {host_name, name}) do
      [{_, field}] -> field
      [] -> nil
    end
  rescue
    ArgumentError -> nil
  end

  # -- emitting ----------------------------------------------------------------------

  @doc """
  Emits signal `name` of strength `strength` at `host` (see the moduledoc for the options
  and laws). Returns `:ok` once the host holds it and has sent it to its neighbours; the
  rest of the field forms asynchronously (`settle/0` waits for it on one node).

  Options:

  #{Options.docs(@schema)}
  """
  @spec emit(Tartarus.host_ref(), name(), number(), keyword()) :: :ok | {:error, term()}
  def emit(host, name, strength, opts \\ []) do
    with {:ok, e} <- emission(strength, opts), do: overlay_call(host, {:emit, name, e})
  end

  @doc """
  Waits until no overlay process of this node (`Tartarus.Overlay` and each host's) has a
  pending message (signal relays, broadcasts) and no relay to a host of this node is still
  in flight over a link with a latency, so every field that only involves this node's hosts
  is complete and every broadcast between them delivered (for tests and step-driven
  emulations that run all hosts in one VM; it does not wait for other nodes). It waits on
  `Tartarus.Clock` (in virtual time the relays in flight arrive meanwhile).

  Returns `:ok`, or `{:error, :timeout}` when there were still messages to handle after
  `timeout` ms: the fields may then be incomplete.
  """
  @spec settle(timeout()) :: :ok | {:error, :timeout}
  def settle(timeout \\ 30_000) do
    deadline =
      if timeout == :infinity, do: :infinity, else: Clock.monotonic_time(:millisecond) + timeout

    do_settle(deadline, 0)
  end

  # Idle twice in a row (a relay being handled sends the next one before its process waits).
  defp do_settle(_deadline, 2), do: :ok

  defp do_settle(deadline, n) do
    cond do
      idle?() -> do_settle(deadline, n + 1)
      past?(deadline) -> {:error, :timeout}
      # Not yet: look again after a pause (looking at once keeps a core busy).
      true -> pause_and_settle(deadline)
    end
  end

  defp pause_and_settle(deadline) do
    Clock.sleep(1)
    do_settle(deadline, 0)
  end

  defp idle? do
    overlays =
      Registry.select(Tartarus.HostRegistry, [{{{:overlay, :"$1"}, :"$2", :_}, [], [:"$2"]}])

    Enum.all?([Process.whereis(:tartarus_overlay) | overlays], &quiet?/1) and
      Enum.all?(:ets.tab2list(:tartarus_overlay_in_flight), fn {name, n} ->
        n <= 0 or Host.overlay_pid(name) == nil
      end)
  end

  defp quiet?(nil), do: true

  defp quiet?(pid) do
    case Process.info(pid, [:message_queue_len, :status]) do
      [message_queue_len: 0, status: :waiting] -> true
      nil -> true
      _ -> false
    end
  end

  defp past?(:infinity), do: false
  defp past?(deadline), do: Clock.monotonic_time(:millisecond) > deadline

  @doc """
  Watches signal `name` at `host` (on any node): `pid` receives
  `{:tartarus_signal, host, name}` each time the host takes a new contribution to it (see
  "Watching" above). Watching twice is the same as once.

      iex> {:ok, _} = Tartarus.start_host(:sw_a)
      iex> {:ok, _} = Tartarus.start_host(:sw_b, neighbours: [:sw_a])
      iex> :ok = Tartarus.Signal.watch(:sw_b, :food)
      iex> Tartarus.emit_signal(:sw_a, :food, 10, span: 2)
      :ok
      iex> b = Tartarus.Host.address(:sw_b)
      iex> require Tartarus.Clock
      iex> Tartarus.Clock.receive do {:tartarus_signal, ^b, :food} -> :arrived after 5_000 -> :missed end
      :arrived
      iex> Enum.each([:sw_a, :sw_b], &Tartarus.stop_host/1)
  """
  @spec watch(Tartarus.host_ref(), name(), pid()) :: :ok | {:error, term()}
  def watch(host, name, pid \\ self()), do: overlay_call(host, {:watch, name, pid})

  @doc "Ends a watch made with `watch/3`."
  @spec unwatch(Tartarus.host_ref(), name(), pid()) :: :ok | {:error, term()}
  def unwatch(host, name, pid \\ self()), do: overlay_call(host, {:unwatch, name, pid})

  @doc "The processes watching signal `name` at `host` (a host on this node)."
  @spec watchers(Tartarus.host_ref(), name()) :: [pid()]
  def watchers(host, name) do
    {host_name, _} = Host.address(host)
    for {_, pid} <- :ets.lookup(:tartarus_signal_watchers, {host_name, name}), do: pid
  end

  defp overlay_call(host, request), do: Host.overlay_call(host, request)

  # -- inside the overlay process ----------------------------------------------------

  @doc false
  # The emitting host takes its own signal (hops 0) and sends it on. `info` is the host's
  # info map. Returns :ok.
  def handle_emit(info, name, e) do
    now = now_us()
    e = Map.put(e, :id, {info.ref, System.unique_integer([:monotonic])})

    Events.emit(
      info,
      %{type: :signal, host: info.ref, name: name, strength: e.strength, span: e.span},
      signals: 1
    )

    take(info, name, info.ref, nil, e, 0, now, now)
  end

  @doc false
  # A relay arrived at `info`'s host from neighbour `from`, which holds the signal at
  # `from_hops` hops from `source`, aged `age_us`.
  def handle_relay(info, from, name, source, packed, from_hops, age_us) do
    e = unpack(packed)
    now = now_us()
    born = now - age_us
    {host_name, _} = info.ref
    field = lookup(host_name, name) || %{own: %{}, nbrs: %{}}
    # What the neighbour announced: the gradient climbs it.
    said = contribution(e, source, from_hops, born)

    field =
      update_in(field, [:nbrs, Access.key(from, %{})], fn by_source ->
        by_source |> Map.put(source, said) |> prune(now)
      end)

    :ets.insert(:tartarus_signals, {{host_name, name}, field})
    take(info, name, source, from, e, from_hops + 1, born, now)
  end

  defp take(info, name, source, from, e, hops, born, now) do
    {host_name, _} = info.ref
    field = lookup(host_name, name) || %{own: %{}, nbrs: %{}}
    c = contribution(e, source, hops, born)

    if hops <= e.span and worth(c, now) > 0 and better?(c, field.own[source], now) do
      own = field.own |> Map.put(source, c) |> prune(now)
      :ets.insert(:tartarus_signals, {{host_name, name}, %{field | own: own}})
      if hops < e.span, do: relay(info, name, source, from, e, hops, now - born)

      for {_, pid} <- :ets.lookup(:tartarus_signal_watchers, {host_name, name}),
          do: send(pid, {:tartarus_signal, info.ref, name})
    end

    :ok
  end

  defp relay(info, name, source, from, e, hops, age_us) do
    targets = info |> Ledger.neighbours() |> List.delete(from)

    bytes =
      Enum.reduce(targets, 0, fn to, acc ->
        msg = {:"$tartarus_signal", to, info.ref, name, source, pack(e), hops, age_us}
        Host.overlay_send(to, msg, Tartarus.Transport.delay(info, to))
        acc + :erlang.external_size(msg)
      end)

    if targets != [] do
      n = length(targets)

      Events.emit(
        info,
        %{
          type: :signal_relay,
          host: info.ref,
          name: name,
          source: source,
          to: targets,
          messages: n,
          bytes: bytes
        },
        signal_messages: n,
        signal_bytes: bytes
      )
    end
  end

  # The emission on the wire: a tuple (a map would repeat its keys in every message).
  defp pack(e),
    do: {e.id, e.strength, e.span, e.lifetime, e.decay, e.lifetime_decay, e.evaporation, e.data}

  @doc false
  def unpack({id, strength, span, lifetime, decay, lifetime_decay, evaporation, data}) do
    %{
      id: id,
      strength: strength,
      span: span,
      lifetime: lifetime,
      decay: decay,
      lifetime_decay: lifetime_decay,
      evaporation: evaporation,
      data: data
    }
  end

  # Drops contributions that evaporated.
  defp prune(by_source, now) do
    by_source |> Enum.filter(fn {_, c} -> worth(c, now) > 0 end) |> Map.new()
  end

  @doc false
  def now_us, do: Clock.monotonic_time(:microsecond)

  defp on_node(host, fun, args), do: Host.on_node(host, __MODULE__, fun, args)
end
