defmodule TartarusImmune.Experiment.HeldOut do
  @moduledoc """
  The held-out test of an immune-selection run (`TartarusImmune.Experiment`): what the
  network, as its live iPkts stand at the end, would choose for test problems it never
  saw, against the cheapest solution of each.
  """

  alias TartarusImmune.{Cache, Domain, Maths}

  @doc """
  How well the network's live iPkts (`live`) choose for the run's held-out test problems:
  accuracy (the cheapest solution chosen), mean regret (absolute and relative), the
  class's known best and the choices made. `st` is the experiment's state.
  """
  @spec test(map(), [map()]) :: map()
  def test(st, live) do
    p = st.p
    domain = st.domain
    pop_order = st.offered

    rows =
      for {set, i} = ref <- st.test_refs do
        inst = domain.instance(set, i, st.seed)
        fx = domain.features(inst)
        chosen = choose(live, fx, p, pop_order)
        costs = Map.new(st.offered, &{&1, Cache.score(domain, &1, ref, st.seed, inst)})
        best = Enum.min_by(st.offered, &costs[&1])
        extra = costs[chosen] - costs[best]
        {chosen, best, extra, extra / max(costs[best], 1)}
      end

    n = max(length(rows), 1)
    {known, _} = Domain.class_best(domain, st.offered, st.test_refs, st.seed)

    %{
      accuracy: Enum.count(rows, fn {c, b, _, _} -> c == b end) / n,
      regret: Enum.sum(Enum.map(rows, &elem(&1, 2))) / n,
      regret_rel: Enum.sum(Enum.map(rows, &elem(&1, 3))) / n,
      known_best: domain.solution_name(known),
      choices: rows |> Enum.map(&domain.solution_name(elem(&1, 0))) |> Enum.frequencies()
    }
  end

  @doc """
  The network's choice for a problem of features `fx` given the live iPkts (maps with
  `:sol`, `:fv`, `:tau`): the solution with most iPkts that recognize `fx` (ties: larger
  summed activation, then the order of `order`); with none, the most populous solution.
  """
  @spec choose([map()], [float()], map(), [module()]) :: module()
  def choose(live, fx, p, order) do
    rec = Enum.filter(live, &Maths.recognizes?(fx, &1.fv, p))
    pool = if rec == [], do: live, else: rec

    case pool do
      [] ->
        hd(order)

      _ ->
        pool
        |> Enum.group_by(& &1.sol)
        |> Enum.min_by(fn {sol, ms} ->
          {-length(ms), -Enum.sum(Enum.map(ms, & &1.tau)),
           Enum.find_index(order, &(&1 == sol)) || 99}
        end)
        |> elem(0)
    end
  end
end
