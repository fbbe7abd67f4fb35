defmodule TartarusImmune.Evolution.MathsTest do
  use ExUnit.Case, async: true

  alias TartarusImmune.Evolution.{ES, NeuralNet, Objective, OrGate, Repertoire}
  alias TartarusTools.Prop

  doctest NeuralNet
  doctest ES
  doctest Repertoire
  doctest Objective
  doctest OrGate

  defp rng(seed), do: :rand.seed_s(:exsss, seed)

  describe "NeuralNet" do
    test "a 2-2-1 network, computed by hand" do
      # h1 = tanh(0.5 * 1 + -1 * 0 + 0.1) = tanh(0.6); h2 = tanh(0 * 1 + 2 * 0 - 0.3) = tanh(-0.3)
      # y = tanh(1 * h1 + -1 * h2 + 0)
      w = [0.5, -1.0, 0.1, 0.0, 2.0, -0.3, 1.0, -1.0, 0.0]
      [y] = NeuralNet.forward([2, 2, 1], w, [1, 0])
      expected = :math.tanh(:math.tanh(0.6) - :math.tanh(-0.3))
      assert_in_delta y, expected, 1.0e-12
    end

    test "a 4-5-2 network with all weights zero outputs zeros; sizes are checked" do
      assert NeuralNet.forward([4, 5, 2], List.duplicate(0.0, 37), [1, 0.5, 0, 1]) == [0.0, 0.0]

      assert_raise ArgumentError, ~r/expected 37 weights/, fn ->
        NeuralNet.forward([4, 5, 2], [0.0], [1, 2, 3, 4])
      end

      assert_raise ArgumentError, ~r/expected 4 inputs/, fn ->
        NeuralNet.forward([4, 5, 2], List.duplicate(0.0, 37), [1])
      end
    end

    test "random weights: the right count, in range, reproducible" do
      {w, _} = NeuralNet.random([4, 5, 2], rng(3), 2.0)
      assert length(w) == 37 and Enum.all?(w, &(abs(&1) <= 2.0))
      assert elem(NeuralNet.random([4, 5, 2], rng(3), 2.0), 0) == w
    end
  end

  describe "ES" do
    test "mutation is N(0, sigma) per weight: mean near 0, standard deviation near sigma" do
      {w, _} = ES.mutate(List.duplicate(0.0, 20_000), 0.3, 100.0, rng(1))
      mean = Enum.sum(w) / length(w)
      sd = :math.sqrt(Enum.sum(Enum.map(w, &((&1 - mean) * (&1 - mean)))) / length(w))
      assert abs(mean) < 0.01
      assert abs(sd - 0.3) < 0.01
    end

    test "mutated weights are clamped to [-w_max, w_max]" do
      {w, _} = ES.mutate(List.duplicate(3.9, 1000), 2.0, 4.0, rng(2))
      assert Enum.all?(w, &(&1 >= -4.0 and &1 <= 4.0))
      assert Enum.any?(w, &(&1 == 4.0))
    end

    test "sigma doubles on each failure up to sigma_max and resets on a success" do
      es = ES.new([0.0], fitness: 1.0, sigma_min: 0.5, sigma_max: 3.0)
      es = Enum.reduce(1..3, es, fn _, es -> ES.tell(es, {:offspring, [1.0]}, 0.0) end)
      assert es.sigma == 3.0
      assert es.champion == [0.0] and es.evaluations == 3
      es = ES.tell(es, {:offspring, [2.0]}, 2.0)
      assert {es.sigma, es.champion, es.fitness, es.improvements} == {0.5, [2.0], 2.0, 1}
    end

    test "re-evaluation replaces the champion's fitness and proposes the champion itself" do
      es = ES.new([0.7], fitness: 5.0, p_reeval: 1.0)
      assert {:champion, [0.7], _} = ES.propose(es, rng(1))
      assert ES.tell(es, {:champion, [0.7]}, 1.0).fitness == 1.0
    end

    test "the (1+1) strategy learns OR on a 2-3-1 network" do
      {w, r} = NeuralNet.random(OrGate.shape(), rng(5))
      es = %{ES.new(w) | fitness: OrGate.fitness(w)}

      {es, _} =
        Enum.reduce(1..400, {es, r}, fn _, {es, r} ->
          {kind, w, r} = ES.propose(es, r)
          {ES.tell(es, {kind, w}, OrGate.fitness(w)), r}
        end)

      assert OrGate.solved?(es.champion)
    end

    test "adopting a foreign controller only when it is better" do
      es = ES.new([0.0], fitness: 0.5)
      assert {:kept, ^es} = ES.adopt(es, [1.0], 0.4)
      assert {:adopted, %{champion: [1.0], fitness: 0.9}} = ES.adopt(es, [1.0], 0.9)
    end
  end

  describe "Repertoire (Algorithm 5)" do
    test "a new antibody, its paratope the epitope, when nothing matches" do
      rep = Repertoire.new(epsilon: 0.2, shape: [2, 1], origin: :r1)
      {rep, [key], _} = Repertoire.recognize(rep, [0.5, 0.5], rng(1))
      ab = rep.antibodies[key]
      assert {ab.id, ab.origin, ab.paratope, ab.concentration} == {1, :r1, [0.5, 0.5], 0.1}
      {rep, [key2], _} = Repertoire.recognize(rep, [0.9, 0.9], rng(2))
      assert rep.antibodies[key2].id == 2
    end

    test "candidates are stimulated in proportion to their affinity" do
      rep = Repertoire.new(epsilon: 0.5, shape: [1, 1], stimulation: 1.0)
      {rep, [a], r} = Repertoire.recognize(rep, [0.0], rng(1))
      # 0.25 from the paratope: 1 - 0.25 / 0.5 = 0.5 more concentration
      {rep, [^a], _} = Repertoire.recognize(rep, [0.25], r)
      assert_in_delta rep.antibodies[a].concentration, 0.1 + 0.5, 1.0e-12
    end

    test "an epsilon covering the whole space keeps one antibody; a smaller one makes more" do
      eps =
        for _ <- 1..300, do: [:rand.uniform(), :rand.uniform(), :rand.uniform(), :rand.uniform()]

      count = fn epsilon ->
        rep = Repertoire.new(epsilon: epsilon)

        {rep, _} =
          Enum.reduce(eps, {rep, rng(9)}, fn ep, {rep, r} ->
            {rep, _, r} = Repertoire.recognize(rep, ep, r)
            {rep, r}
          end)

        map_size(rep.antibodies)
      end

      assert count.(2.0) == 1
      assert count.(0.45) > 1
      assert count.(0.25) > count.(0.45)
    end

    test "the best candidate by concentration; a matching shared one with p_sharing 1" do
      rep = Repertoire.new(epsilon: 0.5, shape: [1, 1], p_sharing: 0.0)
      {rep, [a], r} = Repertoire.recognize(rep, [0.0], rng(1))
      {rep, [b], r} = Repertoire.recognize(rep, [0.9], r)
      rep = Repertoire.report(rep, b, 5.0)
      {rep, cands, r} = Repertoire.recognize(rep, [0.45], r)
      assert Enum.sort(cands) == Enum.sort([a, b])
      assert {_, ^b, :internal, _} = Repertoire.select(rep, cands, [0.45], %{}, r)

      shared = %{
        {:r2, 1} => %{rep.antibodies[a] | origin: :r2, concentration: 99.0},
        {:r2, 2} => %{rep.antibodies[a] | origin: :r2, paratope: [5.0], concentration: 999.0}
      }

      rep1 = %{rep | p_sharing: 1.0}
      assert {rep2, {:r2, 1}, :external, _} = Repertoire.select(rep1, cands, [0.45], shared, r)
      assert Map.has_key?(rep2.antibodies, {:r2, 1})
    end

    test "report averages the fitness into the concentration and purges at zero" do
      rep = Repertoire.new(epsilon: 0.5, shape: [1, 1])
      {rep, [a], _} = Repertoire.recognize(rep, [0.0], rng(1))
      assert Repertoire.report(rep, a, 0.3).antibodies[a].concentration == 0.2
      assert Repertoire.report(rep, a, -0.1).antibodies == %{}
    end

    test "property: every epitope is within epsilon of some paratope after recognize" do
      property =
        :proper.forall(
          {:proper_types.list({:proper_types.float(0.0, 1.0), :proper_types.float(0.0, 1.0)}),
           :proper_types.float(0.05, 1.5)},
          fn {points, epsilon} ->
            Prop.safely(fn ->
              rep = Repertoire.new(epsilon: epsilon, shape: [2, 1])

              {rep, _} =
                Enum.reduce(points, {rep, rng(1)}, fn {x, y}, {rep, r} ->
                  {rep, _, r} = Repertoire.recognize(rep, [x, y], r)
                  {rep, r}
                end)

              Enum.all?(points, fn {x, y} -> Repertoire.candidates(rep, [x, y]) != [] end)
            end)
          end
        )

      assert Prop.check(property, 200) == true
    end
  end

  describe "objective functions (Eqs. 7.1-7.3) on hand-made traces" do
    @still %{v_trans: 0.0, v_rot: 0.0, d: 1.0, light: [0.1, 0.1], puck: false}
    @run_at_light %{v_trans: 1.0, v_rot: 0.0, d: 1.0, light: [0.9, 0.6], puck: false}
    @spinning_at_wall %{v_trans: 0.4, v_rot: 1.0, d: 0.05, light: [0.1, 0.0], puck: false}

    test "S1: running straight towards the light beats standing still and spinning at a wall" do
      s1 = fn trace -> Objective.fitness(:s1, trace) end
      assert_in_delta s1.(List.duplicate(@run_at_light, 10)), 19.0, 1.0e-9
      assert_in_delta s1.(List.duplicate(@still, 10)), 1.0, 1.0e-9
      assert_in_delta s1.(List.duplicate(@spinning_at_wall, 10)), 1.0, 1.0e-9
    end

    test "S2 rewards pushing a puck, under both readings of f_puck" do
      pushing = %{@run_at_light | puck: true}

      for r <- [:product, :sum] do
        gain =
          Objective.fitness(:s2, [pushing], puck_reward: r) -
            Objective.fitness(:s2, [@run_at_light], puck_reward: r)

        assert gain == 1.0
      end
    end

    test "f_puck: the product pays only moving with a puck, the sum pays holding one and moving anywhere" do
      holding_still = %{@still | puck: true}
      assert Objective.f_puck(holding_still, :product) == 0.0
      assert Objective.f_puck(holding_still, :sum) == 1.0
      assert Objective.f_puck(@run_at_light, :product) == 0.0
      assert Objective.f_puck(@run_at_light, :sum) == 1.0
      assert Objective.f_puck(%{@run_at_light | puck: true}, :product) == 1.0
      assert Objective.f_puck(%{@run_at_light | puck: true}, :sum) == 2.0
      assert Objective.step(:s2, holding_still) == Objective.step(:s2, holding_still, :product)
    end

    # 30 steps (3 s) of a robot driving a tight circle at speed, away from walls, never
    # meeting a puck; and of a puck pusher that searches for 20 steps (slower, turning
    # towards the light, a wall at mid range) and then pushes a puck towards the light for
    # 10 (slow, nearly straight, the light brighter).
    @circling List.duplicate(
                %{v_trans: 0.8, v_rot: 0.4, d: 1.0, light: [0.35, 0.3], puck: false},
                30
              )
    @pushing List.duplicate(
               %{v_trans: 0.5, v_rot: 0.3, d: 0.6, light: [0.4, 0.2], puck: false},
               20
             ) ++
               List.duplicate(
                 %{v_trans: 0.5, v_rot: 0.1, d: 0.5, light: [0.7, 0.6], puck: true},
                 10
               )

    test "S2: the sum ranks circling above pushing a puck to the light, the product the reverse" do
      f = fn trace, r -> Objective.fitness(:s2, trace, puck_reward: r) end
      assert_in_delta f.(@circling, :sum), 30 * (0.48 + 0.35 + 0.8), 1.0e-9

      assert_in_delta f.(@pushing, :sum),
                      20 * (0.21 + 0.4 + 0.5) + 10 * (0.225 + 0.7 + 1.5),
                      1.0e-9

      assert_in_delta f.(@circling, :product), 30 * (0.48 + 0.35), 1.0e-9
      assert_in_delta f.(@pushing, :product), 20 * (0.21 + 0.4) + 10 * (0.225 + 0.7 + 0.5), 1.0e-9
      assert f.(@circling, :sum) > f.(@pushing, :sum)
      assert f.(@pushing, :product) > f.(@circling, :product)
      # the default is the product
      assert Objective.fitness(:s2, @pushing) == f.(@pushing, :product)
    end

    test "S3 with the light on ranks as S2; with it off, neither reading of f_puck counts" do
      on = fn trace -> Enum.map(trace, &Map.put(&1, :light_on, true)) end
      off = fn trace -> Enum.map(trace, &Map.put(&1, :light_on, false)) end
      f = fn trace, r -> Objective.fitness(:s3, trace, puck_reward: r) end
      assert f.(on.(@circling), :sum) > f.(on.(@pushing), :sum)
      assert f.(on.(@pushing), :product) > f.(on.(@circling), :product)
      assert f.(off.(@pushing), :sum) == f.(off.(@pushing), :product)
      # light off: moving on without a puck beats pushing one
      assert f.(off.(@circling), :product) > f.(off.(@pushing), :product)
    end

    test "an unknown reading is refused, naming the key" do
      assert_raise ArgumentError, ~r/:puck_reward: expected :product or :sum, got: :max/, fn ->
        Objective.fitness(:s2, @circling, puck_reward: :max)
      end
    end

    test "S3 rewards a puck with the light on and moving without one with the light off" do
      on = Map.merge(@run_at_light, %{puck: true, light_on: true})
      off_with = Map.merge(@run_at_light, %{puck: true, light_on: false})
      off_without = Map.put(@run_at_light, :light_on, false)
      assert Objective.step(:s3, on) == 1.0 + 0.9 + 1.0
      assert Objective.step(:s3, on, :sum) == 1.0 + 0.9 + 2.0
      assert Objective.step(:s3, off_with) == 1.0 + 0.9
      assert Objective.step(:s3, off_without) == 1.0 + 0.9 + 1.0
      assert Objective.step(:s3, off_without, :sum) == 1.0 + 0.9 + 1.0
    end
  end
end
