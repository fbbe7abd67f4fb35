defmodule Tartarus.OverlayHostTest do
  # Each host has its own overlay process: a host flooded with relays queues them in its own
  # mailbox and no other host's signal waits behind them (the issue's "per-host services").
  use Tartarus.HostCase, async: false

  alias Tartarus.{Clock, Host, Signal}
  require Tartarus.Clock

  defmodule Latency do
    # A transport whose every link costs 20 ms one way (and nothing for hand-offs).
    @behaviour Tartarus.Transport
    @impl true
    def hand_off(_host, _dest, rng), do: {:ok, rng}
    @impl true
    def message_delay(_from, _to), do: 20
  end

  @flood 10_000

  # 10,000 relays for host `b` from its neighbour `a`, each of another signal (so each one is
  # taken and kept in a field of its own).
  defp flood(a, b) do
    pid = Host.overlay_pid(b)

    for i <- 1..@flood do
      source = {addr(a), i}
      packed = {source, 100, 2, :infinity, {:linear, 1.0}, :none, :linear, nil}
      send(pid, {:"$tartarus_signal", addr(b), addr(a), {:flood, i}, source, packed, 0, 0})
    end

    pid
  end

  defp flooded?(b), do: Enum.all?(1..@flood, &(Tartarus.signal(b, {:flood, &1}) > 0))

  test "each host has its own overlay process, and the node's door is none of them" do
    [a, b] = line!(2)
    pa = Host.overlay_pid(a)
    pb = Host.overlay_pid(b)
    assert is_pid(pa) and is_pid(pb) and pa != pb
    refute Process.whereis(:tartarus_overlay) in [pa, pb]
  end

  test "a host flooded with 10,000 relays does not hold up another host's signal" do
    [a, b] = line!(2)
    [c, d] = line!(2)
    :ok = Signal.watch(d, :alarm)
    flooded = flood(a, b)
    :ok = Tartarus.emit_signal(c, :alarm, 10, span: 2)
    dd = addr(d)
    assert_receive {:tartarus_signal, ^dd, :alarm}, 5_000
    # d took c's signal while b still had relays of the flood to handle.
    {:message_queue_len, left} = Process.info(flooded, :message_queue_len)
    assert left > 0, "the flooded host's overlay had emptied its mailbox first"
    assert Tartarus.signal(d, :alarm) == 5.0
    :ok = Signal.settle()
    assert flooded?(b)
  end

  test "in virtual time a flood of another host delays a signal by exactly its link's cost" do
    Tartarus.Transport.install(Latency)
    on_exit(&Tartarus.Transport.clear/0)

    Clock.Virtual.run([seed: 3], fn ->
      [a, b] = line!(2)
      [c, d] = line!(2)
      :ok = Signal.watch(d, :alarm)
      _ = flood(a, b)
      t0 = Clock.monotonic_time(:millisecond)
      :ok = Tartarus.emit_signal(c, :alarm, 10, span: 2)
      dd = addr(d)

      Clock.receive do
        {:tartarus_signal, ^dd, :alarm} -> :ok
      after
        60_000 -> flunk("no signal at d")
      end

      assert Clock.monotonic_time(:millisecond) - t0 == 20
      :ok = Signal.settle()
      assert flooded?(b)
    end)
  end
end
