defmodule TartarusLats.BadReadingsTest do
  # Malformed readings, from a bridge writing into the receiver or from a receiver of
  # another make, are refused and counted and never stop a node or the driver.
  use ExUnit.Case, async: false
  doctest TartarusLats.BeaconPlugin

  alias TartarusLats.{BeaconPlugin, DatabaseAgent, World}

  @tag_a {"12121212b64445208f0c720eaf059935", 1, 2}
  @junk %{
    "not a tag" => -60,
    {"12121212B64445208F0C720EAF059935", 1, 2} => -60,
    {"12121212b64445208f0c720eaf059935", 70_000, 2} => -60,
    {"12121212b64445208f0c720eaf059935", 1, 3} => -300,
    {"12121212b64445208f0c720eaf059935", 1, 4} => :loud
  }

  defp host!(prefix) do
    name = "#{prefix}#{System.unique_integer([:positive])}"
    {:ok, host} = Tartarus.start_host(name)
    on_exit(fn -> Tartarus.stop_host(host) end)
    host
  end

  test "a write keeps the valid readings and counts the refused ones" do
    host = host!("badrd")
    :ok = Tartarus.attach_plugin(host, :beacon, {BeaconPlugin, node: :p1})
    :ok = Tartarus.write_plugin(host, :beacon, {:readings, 5, Map.put(@junk, @tag_a, -61)})
    assert Tartarus.read_plugin(host, :beacon, {:scan, 5}) == {:ok, %{@tag_a => -61}}
    assert Tartarus.read_plugin(host, :beacon, :refused) == {:ok, map_size(@junk)}
  end

  test "a receiver that returns junk: the database agent takes only what is well formed" do
    host = host!("badag")
    script = %{1 => Map.put(@junk, @tag_a, -55), 2 => %{@tag_a => -56}}
    :ok = Tartarus.attach_plugin(host, :beacon, {BeaconPlugin, node: :p1, script: script})
    {:ok, _} = Tartarus.create_static_agent(host, DatabaseAgent, %{node: :p1}, name: "lats-db")

    for t <- 1..2,
        do:
          assert(
            {:ok, {:ok, %{sent: _}}} = Tartarus.request({"lats-db", host}, {:sense, t}, 5_000)
          )

    # The valid tag is tracked; none of the junk keys is.
    filtered = Tartarus.store_get(host, {:lats, :filtered}, %{})
    assert Map.keys(filtered) == [@tag_a]
    assert Tartarus.request({"lats-db", host}, {:sense, 3}, 5_000) |> elem(0) == :ok
  end

  test "the world's readings are all well formed" do
    world = World.new()

    {readings, _} =
      World.readings(
        World.step(world, TartarusLats.Radio.seed(1)) |> elem(0),
        TartarusLats.Radio.seed(2)
      )

    for {_node, heard} <- readings,
        {tag, rssi} <- heard,
        is_integer(rssi),
        do: assert(BeaconPlugin.valid_reading?({tag, rssi}))
  end
end
