defmodule Tartarus.StrategyTest do
  # Strategies as pure functions, then as agents walking real (virtual) hosts.
  use Tartarus.HostCase, async: false

  alias Tartarus.Strategy
  alias Tartarus.Test.PickStrategy

  doctest Strategy

  defp rng(seed \\ 1), do: :rand.seed_s(:exsss, {seed, 2, 3})

  defp info(neighbours, visits \\ %{}, gradients \\ %{}) do
    %{here: {:here, :n}, neighbours: neighbours, visits: visits, gradients: gradients}
  end

  @ns [{:b, :n}, {:c, :n}, {:d, :n}]

  describe "choose/3" do
    test "every strategy fails without neighbours" do
      for s <- [:random, :conscientious, {:gradient, :x}, {:strategy, PickStrategy, :b}] do
        assert Strategy.choose(s, info([]), rng()) == {:error, :no_neighbours}
      end
    end

    test ":random picks a neighbour, reproducibly for a seed, and covers all of them" do
      picks =
        Enum.map_reduce(1..200, rng(), fn _, r ->
          {:ok, dest, r} = Strategy.choose(:random, info(@ns), r)
          {dest, r}
        end)
        |> elem(0)

      assert Enum.all?(picks, &(&1 in @ns))
      assert Enum.sort(Enum.uniq(picks)) == @ns
      assert {:ok, d1, _} = Strategy.choose(:random, info(@ns), rng(7))
      assert {:ok, ^d1, _} = Strategy.choose(:random, info(@ns), rng(7))
    end

    test ":conscientious picks an unvisited neighbour, else the least visited" do
      visits = %{{:b, :n} => 1, {:c, :n} => 3}

      for seed <- 1..20 do
        assert {:ok, {:d, :n}, _} = Strategy.choose(:conscientious, info(@ns, visits), rng(seed))
      end

      visits = %{{:b, :n} => 2, {:c, :n} => 1, {:d, :n} => 5}
      assert {:ok, {:c, :n}, _} = Strategy.choose(:conscientious, info(@ns, visits), rng())
    end

    test ":conscientious breaks ties at random" do
      picks =
        for seed <- 1..50, do: elem(Strategy.choose(:conscientious, info(@ns), rng(seed)), 1)

      assert length(Enum.uniq(picks)) > 1
    end

    test "{:gradient, signal} picks the strongest neighbour carrying the signal" do
      g = %{heat: %{{:b, :n} => 1, {:c, :n} => 9, {:elsewhere, :n} => 100}}
      assert {:ok, {:c, :n}, _} = Strategy.choose({:gradient, :heat}, info(@ns, %{}, g), rng())
    end

    test "{:gradient, signal} falls back to conscientious without the signal" do
      visits = %{{:b, :n} => 1, {:c, :n} => 1}
      g = %{cold: %{{:b, :n} => 1}}
      assert {:ok, {:d, :n}, _} = Strategy.choose({:gradient, :heat}, info(@ns, visits, g), rng())

      assert {:ok, {:d, :n}, _} =
               Strategy.choose(
                 {:gradient, :heat},
                 Map.delete(info(@ns, visits), :gradients),
                 rng()
               )
    end

    test "{:strategy, module, arg} calls the module" do
      assert {:ok, {:c, :n}, _} = Strategy.choose({:strategy, PickStrategy, :c}, info(@ns), rng())

      assert Strategy.choose({:strategy, PickStrategy, :z}, info(@ns), rng()) ==
               {:error, {:no_such_neighbour, :z}}
    end

    test "a module that is not a strategy, or an unknown strategy, is an error" do
      assert Strategy.choose({:strategy, String, 1}, info(@ns), rng()) ==
               {:error, {:bad_strategy, {:strategy, String, 1}}}

      assert Strategy.choose(:nearest, info(@ns), rng()) == {:error, {:bad_strategy, :nearest}}
    end
  end

  test "strategy?/1" do
    for s <- [:random, :conscientious, {:gradient, :x}, {:strategy, PickStrategy, nil}] do
      assert Strategy.strategy?(s)
    end

    for s <- [:a, "random", {:strategy, "m", 1}, {:gradient}, nil, {:a, :b}] do
      refute Strategy.strategy?(s)
    end
  end

  describe "agents walking hosts" do
    test ":conscientious visits every host of a ring of 5 without revisiting" do
      # The creation host counts as visited: 4 moves reach the 4 other hosts, each once.
      [home | others] = ring!(5)

      for seed <- 1..5 do
        {:ok, id} =
          Tartarus.create_mobile_agent(home, Walker, {:conscientious, 4},
            owner: self(),
            seed: seed
          )

        assert_receive {:tartarus_result, ^id, path}, 5_000
        assert Enum.sort(path) == Enum.sort(Enum.map(others, &addr/1))
      end
    end

    test ":random walks along links only" do
      hosts = [a, b, c] = line!(3)
      {:ok, id} = Tartarus.create_mobile_agent(a, Walker, {:random, 20}, owner: self())
      assert_receive {:tartarus_result, ^id, path}, 5_000
      assert length(path) == 20
      assert Enum.all?(path, &(&1 in Enum.map(hosts, fn h -> addr(h) end)))
      # From the ends of the line the only way is to the middle.
      [{:start, addr(a)} | Enum.map(path, &{:at, &1})]
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.each(fn [{_, from}, {_, to}] ->
        assert to in Tartarus.neighbours(from)
      end)

      assert addr(b) in path
      _ = c
    end

    test "the same seed gives the same walk" do
      hosts = ring!(4)

      walk = fn ->
        {:ok, id} =
          Tartarus.create_mobile_agent(hd(hosts), Walker, {:random, 8},
            owner: self(),
            seed: :fixed
          )

        assert_receive {:tartarus_result, ^id, path}, 5_000
        path
      end

      assert walk.() == walk.()
    end

    test "{:gradient, signal} follows the host store entry {:gradient, signal}" do
      [a, b, c, d] = hosts!(4)
      for n <- [b, c, d], do: :ok = Tartarus.connect(a, n)

      :ok =
        Tartarus.store_put(a, {:gradient, :danger}, %{
          addr(b) => 0.1,
          addr(c) => 0.9,
          addr(d) => 0.5
        })

      id = agent!(a)
      assert Tartarus.move({id, a}, {:gradient, :danger}) == :ok
      assert Tartarus.whereis(id) == {:ok, addr(c)}
    end

    test "{:strategy, module, arg} moves where the module says" do
      [a, b, c] = hosts!(3)
      :ok = Tartarus.connect(a, b)
      :ok = Tartarus.connect(a, c)
      id = agent!(a)
      assert Tartarus.move({id, a}, {:strategy, PickStrategy, c}) == :ok
      assert Tartarus.whereis(id) == {:ok, addr(c)}

      assert Tartarus.move({id, a}, {:strategy, PickStrategy, :nobody}) ==
               {:error, {:no_such_neighbour, :nobody}}

      assert_receive {:probe_move_failed, ^id, {:strategy, PickStrategy, :nobody},
                      {:no_such_neighbour, :nobody}, _}
    end

    test "a walker's failed move reaches handle_move_failed/4" do
      a = host!()
      {:ok, id} = Tartarus.create_mobile_agent(a, Walker, {:random, 3}, owner: self())
      assert_receive {:tartarus_result, ^id, {:failed, :no_neighbours, []}}
    end
  end
end
