defmodule Tartarus.NamesTest do
  # Agent names and every key derived from an id are unique for at least 10 million agents.
  use Tartarus.HostCase, async: false

  alias Tartarus.Envelope

  doctest Tartarus.Envelope, only: [default_name: 2, clone_name: 2]

  test "arithmetic: 10 million 64-bit ids collide with probability below 3e-6" do
    n = 10_000_000
    bound = n * (n - 1) / 2 / :math.pow(2, 64)
    assert bound < 3.0e-6
    # An id carries 64 random bits (16 hex characters).
    assert byte_size(Envelope.new_id()) == 16
    assert Envelope.new_id() =~ ~r/\A[0-9a-f]{16}\z/
  end

  # 250,000 names: with the old 6-hex-character names about n^2 / 2 / 2^24 = 1,860 pairs
  # would collide, so the sample tells the schemes apart; it takes a few seconds.
  @sample 250_000
  @tag timeout: 180_000
  test "sampled: 250,000 default and clone names, zero collisions" do
    ids = for _ <- 1..@sample, do: Envelope.new_id()
    assert MapSet.size(MapSet.new(ids)) == @sample

    defaults = MapSet.new(ids, &Envelope.default_name(Probe, &1))
    assert MapSet.size(defaults) == @sample

    # Clones of one agent (the worst case: same parent name) stay apart, and so do clones
    # of clones.
    clones = MapSet.new(ids, &Envelope.clone_name("walker/0123456789abcdef", &1))
    assert MapSet.size(clones) == @sample
    assert MapSet.disjoint?(clones, defaults)
  end

  test "a created agent's default name and a clone's name contain their whole ids" do
    [a] = hosts!(1)
    {:ok, id} = Tartarus.create_mobile_agent(a, Tartarus.Examples.Echo, nil)
    [info] = Enum.filter(Tartarus.agents(a), &(&1.id == id))
    assert info.name == "Tartarus.Examples.Echo-" <> id

    assert Envelope.clone_name(info.name, "fedcba9876543210") ==
             "Tartarus.Examples.Echo-#{id}/fedcba9876543210"
  end
end
