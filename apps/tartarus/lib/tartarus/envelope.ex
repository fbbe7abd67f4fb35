defmodule Tartarus.Envelope do
  @moduledoc """
  What an agent is when it travels: identity, code references, state and payload.

  An envelope is plain data. Funs and ports are never part of it (they cannot travel between
  BEAM nodes of different code versions, and DESIGN §6 rules them out); `portable?/1` finds
  them before a migration starts, so a move fails cleanly at the source.

  Fields:

    * `:id` - globally unique (16 hex characters from `:crypto.strong_rand_bytes/1`)
    * `:name` - a human-readable name; the default names (`default_name/2`, `clone_name/2`)
      contain the whole id, so they are as unique as ids (see "Uniqueness")
    * `:module` - the agent's module; `:ships` - other modules it needs wherever it goes
    * `:state` - the agent's state; `:payload` - `%{data: map, modules: [module]}`
    * `:owner` - a pid that receives `{:tartarus_result, id, result}` on `{:return, ...}`
    * `:home` - the host where the agent was created
    * `:hops` - number of completed migrations; `:ttl` - maximum hops (`:infinity` default)
    * `:visits` - `%{host => times visited}` (used by conscientious migration), for the
      `max_visits` hosts it visited most recently (a platform option, 64 by default; see
      `visit/3`); `:visit_order` - those hosts, the most recent first
    * `:from` - the previous host; `:departed_at` - system time in µs of the last departure
    * `:static` - static agents never leave their host
    * `:rng` - the agent's exported `:rand` state, so its random choices travel with it
    * `:clone_of` - the id of the agent this one was cloned from (nil otherwise)
    * `:issuer`, `:signature` - who signed the envelope (see DESIGN §7)

  ## Uniqueness

  An id is 64 random bits. Among `n` ids the probability that any two are equal is at most
  `n * (n - 1) / 2 / 2^64`: about 2.7e-6 for 10 million agents, 2.7e-4 for 100 million.
  Every key derived from an agent's id (its default name, a clone's name, the forwarding
  pointers kept under ids and names) contains the whole id, never a prefix, so it is unique
  whenever the ids are. (Names given by users are theirs to keep apart.)
  """

  @enforce_keys [:id, :module]
  defstruct id: nil,
            name: nil,
            module: nil,
            ships: [],
            state: nil,
            payload: %{data: %{}, modules: []},
            owner: nil,
            home: nil,
            hops: 0,
            ttl: :infinity,
            visits: %{},
            visit_order: [],
            from: nil,
            departed_at: nil,
            static: false,
            rng: nil,
            clone_of: nil,
            issuer: nil,
            signature: nil

  @typedoc "An agent's envelope."
  @type t :: %__MODULE__{}

  @doc """
  A new globally unique agent id.

      iex> id = Tartarus.Envelope.new_id()
      iex> byte_size(id)
      16
  """
  @spec new_id() :: String.t()
  def new_id do
    # 64 bits from the system's strong random source (in virtual time a seeded stream:
    # Tartarus.Clock.unique_bytes/1), as from :crypto.strong_rand_bytes(8) per id, but drawn
    # 64 ids at a time into the calling process's dictionary (one crypto call per 64 ids:
    # creations are this much cheaper).
    <<bits::binary-size(8), rest::binary>> =
      case Process.get(:"$tartarus_id_pool") do
        <<_::binary-size(8), _::binary>> = pool -> pool
        _ -> Tartarus.Clock.unique_bytes(8 * 64)
      end

    Process.put(:"$tartarus_id_pool", rest)
    Base.encode16(bits, case: :lower)
  end

  @doc """
  A new globally unique agent id, as `new_id/0` but drawn alone, leaving nothing in the
  calling process's dictionary: for an agent's own process (a clone's id), which keeps no
  process-dictionary key outside its callbacks.

      iex> id = Tartarus.Envelope.new_id(:unpooled)
      iex> byte_size(id)
      16
  """
  @spec new_id(:unpooled) :: String.t()
  def new_id(:unpooled), do: Base.encode16(Tartarus.Clock.unique_bytes(8), case: :lower)

  @doc """
  The name of an agent created without one: its module and its whole id.

      iex> Tartarus.Envelope.default_name(Tartarus.Examples.Echo, "0123456789abcdef")
      "Tartarus.Examples.Echo-0123456789abcdef"
  """
  @spec default_name(module(), String.t()) :: String.t()
  def default_name(module, id) when is_atom(module), do: module_name(module) <> "-" <> id

  # inspect/1 of a module, without inspect's cost (default names are made on every create).
  defp module_name(module) do
    case Atom.to_string(module) do
      "Elixir." <> name -> name
      name -> ":" <> name
    end
  end

  @doc """
  The name of a clone with id `id` of an agent named `name`: the name's root (a clone's name
  without its `/<id>` suffix, so names do not grow from clone to clone) and the clone's whole id.

      iex> Tartarus.Envelope.clone_name("walker", "0123456789abcdef")
      "walker/0123456789abcdef"
      iex> Tartarus.Envelope.clone_name("walker/0123456789abcdef", "fedcba9876543210")
      "walker/fedcba9876543210"
      iex> Tartarus.Envelope.clone_name({:team, 1}, "0123456789abcdef")
      "{:team, 1}/0123456789abcdef"
  """
  @spec clone_name(term(), String.t()) :: String.t()
  def clone_name(name, id), do: root(name) <> "/" <> id

  defp root(name) when is_binary(name) do
    size = byte_size(name) - 17

    with true <- size >= 0,
         <<root::binary-size(size), ?/, suffix::binary-size(16)>> <- name,
         true <- hex?(suffix) do
      root
    else
      _ -> name
    end
  end

  defp root(name) when is_atom(name) or is_number(name), do: to_string(name)
  defp root(name), do: inspect(name)

  defp hex?(s), do: s |> :binary.bin_to_list() |> Enum.all?(&(&1 in ?0..?9 or &1 in ?a..?f))

  @doc """
  Records a visit of `host`: its count goes up by one and it becomes the most recent of
  `:visit_order`. At most `max` hosts are remembered: beyond that the least recently visited
  are forgotten, so what an agent carries (and what every hop copies, checks and ships) stays
  bounded however many hosts it has seen. A forgotten host counts as never visited again
  (`Tartarus.Strategy`'s conscientious choice may return to it), and it is not told to drop
  its forwarding pointer when the agent ends (`forward_ttl` sweeps it).

      iex> env = %Tartarus.Envelope{id: "0123456789abcdef", module: Tartarus.Examples.Echo}
      iex> env = env |> Tartarus.Envelope.visit(:a, 2) |> Tartarus.Envelope.visit(:b, 2)
      iex> env = Tartarus.Envelope.visit(env, :a, 2)
      iex> {env.visits, env.visit_order}
      {%{a: 2, b: 1}, [:a, :b]}
      iex> env = Tartarus.Envelope.visit(env, :c, 2)
      iex> {env.visits, env.visit_order}
      {%{a: 2, c: 1}, [:c, :a]}
  """
  @spec visit(t(), Tartarus.host() | term(), pos_integer() | :infinity) :: t()
  def visit(%__MODULE__{visits: visits, visit_order: order} = env, host, max) do
    # (An envelope journaled before `:visit_order` existed is upgraded on restore: upgrade/1.)

    {order, visits} =
      case visits do
        %{^host => n} ->
          {[host | List.delete(order, host)], %{visits | host => n + 1}}

        _ when max != :infinity and map_size(visits) >= max ->
          # Full: the least recent goes (the order lists every key once, see Tartarus.Wire).
          {kept, gone} = :lists.split(max - 1, order)
          {[host | kept], visits |> Map.drop(gone) |> Map.put(host, 1)}

        _ ->
          {[host | order], Map.put(visits, host, 1)}
      end

    %{env | visits: visits, visit_order: order}
  end

  @doc """
  An envelope as this version makes them, from one an earlier version journaled: fields it
  lacks get their defaults, and a missing `:visit_order` lists its `:visits` (so that it
  passes `Tartarus.Wire` when it travels on). A current envelope is returned as it is.

      iex> old = %{__struct__: Tartarus.Envelope, id: "0123456789abcdef", module: Tartarus.Examples.Echo, visits: %{a: 1}}
      iex> Tartarus.Envelope.upgrade(old).visit_order
      [:a]
  """
  @spec upgrade(term()) :: t() | term()
  def upgrade(%{__struct__: __MODULE__} = env) do
    if Map.has_key?(env, :visit_order) and
         map_size(env) == map_size(%__MODULE__{id: nil, module: nil}) do
      env
    else
      order = Map.get(env, :visit_order) || Map.keys(Map.get(env, :visits, %{}))
      struct(__MODULE__, env |> Map.delete(:__struct__) |> Map.put(:visit_order, order))
    end
  end

  # Anything else (the protocol model's stand-in envelopes) is left as it is.
  def upgrade(other), do: other

  @doc "A fresh exported `:rand` state seeded from `seed` (any term)."
  @spec seed_rng(term()) :: term()
  def seed_rng(seed) do
    <<a::32, b::32, c::32, _::binary>> = :crypto.hash(:sha256, :erlang.term_to_binary(seed))
    :rand.export_seed_s(:rand.seed_s(:exsss, {a, b, c}))
  end

  @doc "All modules this agent needs at its destination."
  @spec modules(t()) :: [module()]
  def modules(%__MODULE__{module: m, ships: [], payload: %{modules: []}}), do: [m]

  def modules(%__MODULE__{module: m, ships: ships, payload: %{modules: pm}}) do
    Enum.uniq([m | ships] ++ pm)
  end

  @doc """
  Checks that an envelope can travel: no funs or ports in state or payload.

      iex> Tartarus.Envelope.portable?(%{a: [1, {2, "x"}]})
      :ok
      iex> Tartarus.Envelope.portable?(%{a: [1, fn -> 2 end]})
      {:error, {:not_portable, :fun, [:a, 1]}}
  """
  @spec portable?(term()) :: :ok | {:error, {:not_portable, :fun | :port, list()}}
  def portable?(term) do
    # The common case (portable) without building paths or closures; the path of an
    # offending term is found by the slower walk only when there is one.
    if clean?(term), do: :ok, else: walk(term, [])
  end

  defp clean?(t) when is_function(t) or is_port(t), do: false
  defp clean?([h | t]), do: clean?(h) and clean?(t)
  defp clean?(t) when is_map(t), do: clean_map?(:maps.next(:maps.iterator(t)))
  defp clean?(t) when is_tuple(t), do: clean_tuple?(t, tuple_size(t))
  defp clean?(_t), do: true

  defp clean_map?(:none), do: true
  defp clean_map?({k, v, i}), do: clean?(k) and clean?(v) and clean_map?(:maps.next(i))

  defp clean_tuple?(_t, 0), do: true
  defp clean_tuple?(t, i), do: clean?(:erlang.element(i, t)) and clean_tuple?(t, i - 1)

  defp walk(t, path) when is_function(t), do: {:error, {:not_portable, :fun, Enum.reverse(path)}}
  defp walk(t, path) when is_port(t), do: {:error, {:not_portable, :port, Enum.reverse(path)}}

  defp walk(t, path) when is_list(t) do
    walk_list(t, 0, path)
  end

  # :maps.to_list/1, not Enum: structs (dates, MapSets, ...) are plain data here.
  defp walk(t, path) when is_map(t) do
    t
    |> :maps.to_list()
    |> Enum.reduce_while(:ok, fn {k, v}, :ok ->
      with :ok <- walk(k, [{:key, k} | path]), :ok <- walk(v, [k | path]) do
        {:cont, :ok}
      else
        err -> {:halt, err}
      end
    end)
  end

  defp walk(t, path) when is_tuple(t), do: walk_list(Tuple.to_list(t), 0, path)
  defp walk(_t, _path), do: :ok

  defp walk_list([], _i, _path), do: :ok

  defp walk_list([h | t], i, path) do
    case walk(h, [i | path]) do
      :ok -> walk_list(t, i + 1, path)
      err -> err
    end
  end

  # Improper list tail.
  defp walk_list(t, i, path), do: walk(t, [i | path])
end
