defmodule TartarusEmu.Log.Counts do
  @moduledoc """
  The counting part of the event log, as pure functions over a flat map.

  Keys (all counters are integers):

    * `{:total, counter}` - over the whole network;
    * `{:host, host, counter}` - per host (the host the event happened on);
    * `{:link, from, to, :messages | :bytes}` - per directed link, from `:departure` and
      `:clone` events (one hand-off is one message of its envelope plus shipped code bytes);
    * `{:step, step, counter}` - per step of the log's clock (added by `stamp/2`).

  Counter names are those of `Tartarus.Events` (`:arrivals`, `:departures`, `:bytes`,
  `:broadcasts`, `:broadcast_messages`, `:broadcast_bytes`, `:broadcasts_received`, ...),
  so per-host counts compare directly with `Tartarus.status(host).counts`. One difference:
  the platform also counts shipped code of a `:clone` in `:bytes`, which the clone event
  does not carry.

      iex> alias TartarusEmu.Log.Counts
      iex> c = Counts.add(%{}, %{type: :departure, host: :a, to: :b, bytes: 100, code_bytes: 20})
      iex> {c[{:total, :departures}], c[{:host, :a, :bytes}], c[{:link, :a, :b, :bytes}]}
      {1, 120, 120}
  """

  @typedoc "Flat counts."
  @type t :: %{optional(tuple()) => non_neg_integer()}

  @doc """
  Adds one event (a `Tartarus.Events` map) to the counts.

      iex> TartarusEmu.Log.Counts.add(%{}, %{type: :arrival, host: :b})
      %{{:total, :arrivals} => 1, {:host, :b, :arrivals} => 1}

  A broadcast counts its messages (one per neighbour) and bytes:

      iex> c = TartarusEmu.Log.Counts.add(%{}, %{type: :broadcast, host: :a, to: [:b, :c], messages: 2, bytes: 90})
      iex> {c[{:total, :broadcasts}], c[{:total, :broadcast_messages}], c[{:host, :a, :broadcast_bytes}]}
      {1, 2, 90}
  """
  @spec add(t(), map()) :: t()
  # The hot path of the log (two events per migration): one clause per common type.
  def add(c, %{type: :arrival, host: h}) do
    c |> bump({:total, :arrivals}, 1) |> bump({:host, h, :arrivals}, 1)
  end

  def add(c, %{type: :departure, host: h, to: to} = e) do
    cb = Map.get(e, :code_bytes, 0)
    b = Map.get(e, :bytes, 0) + cb

    c
    |> bump({:total, :departures}, 1)
    |> bump({:host, h, :departures}, 1)
    |> bump({:total, :bytes}, b)
    |> bump({:host, h, :bytes}, b)
    |> bump({:total, :code_bytes}, cb)
    |> bump({:host, h, :code_bytes}, cb)
    |> bump({:link, h, to, :messages}, 1)
    |> bump({:link, h, to, :bytes}, b)
  end

  def add(c, %{type: type, host: host} = e) do
    Enum.reduce(amounts(type, e), c, fn {counter, n}, c ->
      c
      |> bump({:total, counter}, n)
      |> bump({:host, host, counter}, n)
    end)
    |> add_link(type, e)
  end

  defp amounts(:created, _), do: [created: 1]
  defp amounts(:move_failed, _), do: [move_failed: 1]
  defp amounts(:clone, e), do: [clones: 1, bytes: Map.get(e, :bytes, 0)]
  defp amounts(:kill, _), do: [kills: 1]
  defp amounts(:stopped, _), do: [stopped: 1]
  defp amounts(:crash, _), do: [crashes: 1]
  defp amounts(:removed, _), do: [removed: 1]
  defp amounts(:message, e), do: [messages: 1, message_bytes: Map.get(e, :bytes, 0)]
  defp amounts(:refused, _), do: [refused: 1]

  defp amounts(:broadcast, e),
    do: [
      broadcasts: 1,
      broadcast_messages: Map.get(e, :messages, 0),
      broadcast_bytes: Map.get(e, :bytes, 0)
    ]

  defp amounts(:broadcast_received, _), do: [broadcasts_received: 1]
  defp amounts(other, _), do: [{other, 1}]

  defp add_link(c, :clone, %{host: from, to: to} = e) do
    c
    |> bump({:link, from, to, :messages}, 1)
    |> bump({:link, from, to, :bytes}, Map.get(e, :bytes, 0))
  end

  defp add_link(c, _type, _e), do: c

  defp bump(c, key, n) do
    case c do
      %{^key => v} -> %{c | key => v + n}
      _ -> Map.put(c, key, n)
    end
  end

  @doc """
  Adds `delta` into `counts`, also counting its totals under `{:step, step, counter}`.

      iex> TartarusEmu.Log.Counts.stamp(%{{:total, :arrivals} => 2}, 3)
      %{{:total, :arrivals} => 2, {:step, 3, :arrivals} => 2}
  """
  @spec stamp(t(), non_neg_integer()) :: t()
  def stamp(delta, step) do
    Enum.reduce(delta, delta, fn
      {{:total, counter}, n}, acc -> Map.put(acc, {:step, step, counter}, n)
      _, acc -> acc
    end)
  end

  @doc """
  Merges two flat counts.

      iex> TartarusEmu.Log.Counts.merge(%{{:total, :kills} => 1}, %{{:total, :kills} => 2})
      %{{:total, :kills} => 3}
  """
  @spec merge(t(), t()) :: t()
  def merge(a, b) when map_size(a) < map_size(b), do: merge(b, a)
  def merge(big, small), do: Enum.reduce(small, big, fn {k, n}, acc -> bump(acc, k, n) end)

  @doc """
  The counts as nested maps: `%{totals: %{counter => n}, hosts: %{host => %{counter => n}},
  links: %{{from, to} => %{messages: m, bytes: b}}, steps: %{step => %{counter => n}}}`.

      iex> c = TartarusEmu.Log.Counts.add(%{}, %{type: :departure, host: :a, to: :b, bytes: 5, code_bytes: 0})
      iex> TartarusEmu.Log.Counts.nest(c).links
      %{{:a, :b} => %{messages: 1, bytes: 5}}
  """
  @spec nest(t()) :: %{totals: map(), hosts: map(), links: map(), steps: map()}
  def nest(c) do
    Enum.reduce(c, %{totals: %{}, hosts: %{}, links: %{}, steps: %{}}, fn
      {{:total, k}, n}, acc -> put_in(acc, [:totals, k], n)
      {{:host, h, k}, n}, acc -> update_in(acc, [:hosts], &deep_put(&1, h, k, n))
      {{:link, f, t, k}, n}, acc -> update_in(acc, [:links], &deep_put(&1, {f, t}, k, n))
      {{:step, s, k}, n}, acc -> update_in(acc, [:steps], &deep_put(&1, s, k, n))
    end)
  end

  defp deep_put(map, outer, k, n), do: Map.update(map, outer, %{k => n}, &Map.put(&1, k, n))
end
