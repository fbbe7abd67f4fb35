defmodule TartarusLats.BeaconPlugin do
  @moduledoc """
  The BLE receiver of a LATS node, as a `Tartarus.Plugin` (simulated).

  A node's database agent reaches its receiver only through the platform's
  plugin channel: `Tartarus.Agent.read(:beacon, {:scan, t})` returns what the
  receiver heard in second `t` as `%{tag => rssi}` (tags not heard are
  absent). Here the radio is simulated: the receiver asks the emulated
  physical world (`TartarusLats.WorldServer`) what its node hears, or plays
  a script. The real receiver (an HM-10 on the Pi's UART, packets parsed by
  `TartarusLats.IBeacon`) implements the same reads in the firmware; it is
  not written yet.

  Options (one source is required):

    * `:node` - the node (zone) this receiver stands in;
    * `:world` - a `TartarusLats.WorldServer` (pid, name or `{name, node}`):
      scans ask it for this node's readings of the current second;
    * `:script` - `%{second => %{tag => rssi}}` for tests (seconds absent
      from the script hear nothing).

  Reads: `{:scan, t}` (the readings of second `t`; with a world source the
  world must be at second `t`, else `{:error, {:not_now, t, world_time}}`),
  `:last` (the last scan, `{t, readings}` or `nil`). Writes:
  `{:readings, t, readings}` injects readings for second `t` (they take
  precedence over the source), e.g. from a test or a hardware bridge.
  """
  @behaviour Tartarus.Plugin

  @impl true
  def init(opts) do
    node = Keyword.get(opts, :node)

    cond do
      node == nil ->
        {:error, {:bad_option, :node, "expected the node this receiver stands in, got: nil"}}

      Keyword.has_key?(opts, :world) ->
        {:ok, %{node: node, source: {:world, opts[:world]}, injected: %{}, last: nil}}

      is_map(Keyword.get(opts, :script)) ->
        {:ok, %{node: node, source: {:script, opts[:script]}, injected: %{}, last: nil}}

      true ->
        {:error, {:bad_option, :source, "expected a :world or a :script option"}}
    end
  end

  @impl true
  def describe(s) do
    %{kind: :ble_receiver, node: s.node, reads: [:scan, :last], writes: [:readings]}
  end

  @impl true
  def read({:scan, t}, s) when is_integer(t) do
    result =
      case Map.pop(s.injected, t) do
        {readings, injected} when is_map(readings) -> {:ok, readings, %{s | injected: injected}}
        {nil, _} -> {source(s.source, s.node, t), s}
      end

    case result do
      {:ok, readings, s} -> {:ok, readings, %{s | last: {t, readings}}}
      {{:ok, readings}, s} -> {:ok, readings, %{s | last: {t, readings}}}
      {{:error, reason}, s} -> {:error, reason, s}
    end
  end

  def read(:last, s), do: {:ok, s.last, s}
  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  def write({:readings, t, readings}, s) when is_integer(t) and is_map(readings),
    do: {:ok, %{s | injected: Map.put(s.injected, t, readings)}}

  def write(arg, s), do: {:error, {:bad_argument, arg}, s}

  defp source({:script, script}, _node, t), do: {:ok, Map.get(script, t, %{})}

  defp source({:world, world}, node, t) do
    TartarusLats.WorldServer.readings(world, node, t)
  catch
    :exit, reason -> {:error, {:world_unreachable, reason}}
  end
end
