defmodule Tartarus.RandomTest do
  # The random stream that travels with an agent: same seed, same draws, wherever the agent
  # goes; clones get reproducible streams of their own.
  use Tartarus.HostCase, async: false

  alias Tartarus.Random

  doctest Random

  # The draws an agent makes with every function of Tartarus.Agent's random stream.
  defp draws(ref) do
    [
      inside(ref, :uniform),
      inside(ref, :uniform, [1000]),
      inside(ref, :normal),
      inside(ref, :normal, [10.0, 2.0]),
      inside(ref, :shuffle, [Enum.to_list(1..10)]),
      inside(ref, :random_seed)
    ]
  end

  describe "pure streams" do
    test "the same seed gives the same sequence, another seed another" do
      seq = fn seed ->
        Enum.map_reduce(1..20, Random.new(seed), fn _, s -> Random.uniform(s) end) |> elem(0)
      end

      assert seq.({:run, 1}) == seq.({:run, 1})
      assert seq.({:run, 1}) != seq.({:run, 2})
    end

    test "normal/3 has the asked mean and spread" do
      {xs, _} = Enum.map_reduce(1..4000, Random.new(3), fn _, s -> Random.normal(s, 5.0, 2.0) end)
      mean = Enum.sum(xs) / length(xs)
      sd = :math.sqrt(Enum.sum(Enum.map(xs, &((&1 - mean) ** 2))) / length(xs))
      assert abs(mean - 5.0) < 0.15
      assert abs(sd - 2.0) < 0.15
    end

    test "shuffle/2 permutes and depends on the stream" do
      {a, s} = Random.shuffle(Random.new(1), 1..20)
      {b, _} = Random.shuffle(s, 1..20)
      assert Enum.sort(a) == Enum.to_list(1..20)
      assert a != b
      assert Random.shuffle(Random.new(1), []) |> elem(0) == []
    end

    test "fork/1 is deterministic, and the child differs from the parent and siblings" do
      s = Random.new(:p)
      {c1, p1} = Random.fork(s)
      {c2, _} = Random.fork(p1)
      assert Random.fork(s) == {c1, p1}
      first = fn st -> elem(Random.uniform(st), 0) end
      assert length(Enum.uniq([first.(c1), first.(c2), first.(p1)])) == 3
    end
  end

  describe "an agent's stream" do
    test "is seeded from the seed: option (the first draw matches the pure stream)" do
      h = host!()
      id = agent!(h, %{}, seed: {:scenario, 7, 1})
      {expected, _} = Random.uniform(Random.new({:scenario, 7, 1}))
      assert inside({id, h}, :uniform) == expected
    end

    test "gives the same draws across moves as on one host, and differs for another seed" do
      [a, b, c] = line!(3)

      # Run 1: draws on a, b and c, moving in between.
      mover = agent!(a, %{}, seed: 42)
      d1 = draws({mover, a})
      :ok = Tartarus.move({mover, a}, b)
      d2 = draws({mover, a})
      :ok = Tartarus.move({mover, a}, c)
      d3 = draws({mover, a})
      assert Tartarus.whereis(mover) == {:ok, addr(c)}

      # Run 2: the same seed, never moving.
      stayer = agent!(c, %{}, seed: 42)
      assert draws({stayer, c}) ++ draws({stayer, c}) ++ draws({stayer, c}) == d1 ++ d2 ++ d3

      # Another seed, other numbers.
      other = agent!(a, %{}, seed: 43)
      assert draws({other, a}) != d1

      for id <- [mover, stayer, other], do: Tartarus.kill(id)
    end

    test "random strategy moves and draws replay identically for one seed" do
      hosts = ring!(5)
      [a | _] = hosts

      run = fn ->
        id = agent!(a, %{}, seed: :walk)

        trace =
          for _ <- 1..6 do
            x = inside({id, a}, :uniform)
            :ok = Tartarus.move({id, a}, :random)
            {:ok, where} = Tartarus.whereis(id)
            {x, where}
          end

        Tartarus.kill(id)
        trace
      end

      t1 = run.()
      assert t1 == run.()
      # The walk really went places.
      assert length(Enum.uniq(Enum.map(t1, &elem(&1, 1)))) > 1
    end

    test "clones get reproducible streams, different from their parent's and each other's" do
      h = host!()

      run = fn ->
        parent = agent!(h, %{}, seed: :family)
        _ = inside({parent, h}, :uniform)
        :ok = Tartarus.post({parent, h}, {:do, {:clone, :here}})
        assert_receive {:probe_arrived, c1, %{clone_of: ^parent}, _}, 2_000
        :ok = Tartarus.post({parent, h}, {:do, {:clone, :here}})
        assert_receive {:probe_arrived, c2, %{clone_of: ^parent}, _}, 2_000

        result = %{
          parent: draws({parent, h}),
          c1: draws({c1, h}),
          c2: draws({c2, h})
        }

        for id <- [parent, c1, c2], do: Tartarus.kill(id)
        result
      end

      r1 = run.()
      r2 = run.()
      assert r1 == r2
      assert length(Enum.uniq([r1.parent, r1.c1, r1.c2])) == 3
    end

    test "functions of the stream fail outside an agent" do
      assert_raise ArgumentError, fn -> Tartarus.Agent.uniform() end
    end
  end
end
