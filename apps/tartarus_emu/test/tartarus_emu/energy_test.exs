defmodule TartarusEmu.EnergyTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.Energy

  doctest Energy

  test "cost is linear in messages and bytes" do
    params = Energy.params(per_message: 1.0, per_byte: 0.01)
    assert Energy.cost(%{messages: 0, bytes: 0}, params) == 0.0
    assert_in_delta Energy.cost(%{messages: 4, bytes: 250}, params), 6.5, 1.0e-9
    assert Energy.cost(%{}, params) == 0.0
  end

  test "total equals the sum of per-key costs and of per-host costs" do
    links = %{
      {:h1, :h2} => %{messages: 7, bytes: 700},
      {:h2, :h3} => %{messages: 2, bytes: 50},
      {:h3, :h1} => %{messages: 1, bytes: 1}
    }

    total = Energy.total(links)
    assert_in_delta total, links |> Energy.costs() |> Map.values() |> Enum.sum(), 1.0e-9
    assert_in_delta total, links |> Energy.per_host() |> Map.values() |> Enum.sum(), 1.0e-9

    both = Energy.per_host(links, receive_share: 1.0)
    assert_in_delta both |> Map.values() |> Enum.sum(), 2 * total, 1.0e-9
  end

  test "per_host honours custom parameters" do
    params = Energy.params(per_message: 1, per_byte: 0)
    assert Energy.per_host(%{{:a, :b} => %{messages: 3, bytes: 9}}, params: params) == %{a: 3}
  end

  test "bad input is refused with what was expected and what arrived" do
    assert_raise ArgumentError,
                 ~r/expected :per_byte to be a non-negative number \(mJ\), got: -1/,
                 fn ->
                   Energy.params(per_byte: -1)
                 end

    assert_raise ArgumentError,
                 "Energy: expected counts %{messages: non_neg_integer, bytes: non_neg_integer}, got: %{messages: -1}",
                 fn -> Energy.cost(%{messages: -1}) end

    assert_raise ArgumentError, ~r/got: 5/, fn -> Energy.total(%{a: 5}) end

    assert_raise ArgumentError, "Energy.per_host/2: expected link keys {from, to}, got: :a", fn ->
      Energy.per_host(%{a: %{messages: 1}})
    end

    assert_raise ArgumentError, ~r/:receive_share to be a non-negative number, got: :x/, fn ->
      Energy.per_host(%{}, receive_share: :x)
    end
  end
end
