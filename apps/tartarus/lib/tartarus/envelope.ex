defmodule Tartarus.Envelope do
  @moduledoc """
  What an agent is when it travels: identity, code references, state and payload.

  An envelope is plain data. Funs and ports are never part of it (they cannot travel between
  BEAM nodes of different code versions, and DESIGN §6 rules them out); `portable?/1` finds
  them before a migration starts, so a move fails cleanly at the source.

  Fields:

    * `:id` - globally unique (16 hex characters from `:crypto.strong_rand_bytes/1`)
    * `:name` - a human-readable name (not necessarily unique)
    * `:module` - the agent's module; `:ships` - other modules it needs wherever it goes
    * `:state` - the agent's state; `:payload` - `%{data: map, modules: [module]}`
    * `:owner` - a pid that receives `{:tartarus_result, id, result}` on `{:return, ...}`
    * `:home` - the host where the agent was created
    * `:hops` - number of completed migrations; `:ttl` - maximum hops (`:infinity` default)
    * `:visits` - `%{host => times visited}` (used by conscientious migration)
    * `:from` - the previous host; `:departed_at` - system time in µs of the last departure
    * `:static` - static agents never leave their host
    * `:rng` - the agent's exported `:rand` state, so its random choices travel with it
    * `:clone_of` - the id of the agent this one was cloned from (nil otherwise)
    * `:issuer`, `:signature` - who signed the envelope (see DESIGN §7)
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
  def new_id, do: Base.encode16(:crypto.strong_rand_bytes(8), case: :lower)

  @doc "A fresh exported `:rand` state seeded from `seed` (any term)."
  @spec seed_rng(term()) :: term()
  def seed_rng(seed) do
    <<a::32, b::32, c::32, _::binary>> = :crypto.hash(:sha256, :erlang.term_to_binary(seed))
    :rand.export_seed_s(:rand.seed_s(:exsss, {a, b, c}))
  end

  @doc "All modules this agent needs at its destination."
  @spec modules(t()) :: [module()]
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
  def portable?(term), do: walk(term, [])

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
