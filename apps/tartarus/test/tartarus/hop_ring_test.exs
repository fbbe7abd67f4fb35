defmodule Tartarus.HopRingTest do
  use ExUnit.Case, async: true

  alias Tartarus.Ledger

  test "a host's hop ring gives the times recorded, and the last 1,024 once it wraps" do
    host = %{hops: Ledger.new_hop_ring()}
    assert Ledger.hop_times(host) == []

    for t <- 1..5, do: Ledger.record_hop(host, t)
    assert Enum.sort(Ledger.hop_times(host)) == [1, 2, 3, 4, 5]

    # A time of 0 µs is kept too (slots hold t + 1).
    Ledger.record_hop(host, 0)
    assert Enum.sort(Ledger.hop_times(host)) == [0, 1, 2, 3, 4, 5]

    for t <- 6..1_030, do: Ledger.record_hop(host, t)
    times = Ledger.hop_times(host)
    assert length(times) == 1_024
    assert Enum.sort(times) == Enum.to_list(7..1_030)

    :ok = Ledger.reset_hops(host)
    assert Ledger.hop_times(host) == []
  end
end
