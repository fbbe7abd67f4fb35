defmodule TartarusLats.DashboardPanelTest do
  # The LATS panel of the web dashboard, over a real experiment's state after some world
  # seconds: every bearer the receivers heard is shown at a node of the building, and the
  # panel is what the dashboard serves for the experiment (GET /api/panels).
  use ExUnit.Case, async: false

  alias TartarusLats.{Building, DashboardPanel, Experiment}

  test "bearers are shown at the node that heard them loudest; the dashboard serves it" do
    {:ok, opts} = Experiment.validate(nodes: 10, bearers: 4, minutes: 1, queries: 1, out: false)
    setup = opts |> Map.new() |> Map.merge(%{seed: 3, rng: :rand.seed_s(:exsss, 3), steps: 60})
    {:ok, state} = Experiment.setup(setup)

    try do
      state = Enum.reduce(1..20, state, &Experiment.step(&2, &1))
      [{DashboardPanel, arg}] = Experiment.panels(state)
      assert Experiment.network(state) == state.dep.net

      view = DashboardPanel.render(arg)
      assert view.columns == ["what", "who", "node", "detail"]
      bearers = for ["bearer", who, node, _] <- view.rows, do: {who, node}
      assert bearers != []
      names = state.dep.world |> TartarusLats.World.names() |> Enum.map(&to_string/1)
      nodes = state.dep.building |> Building.nodes() |> Enum.map(&to_string/1)
      assert Enum.all?(bearers, fn {who, node} -> who in names and node in nodes end)

      {:ok, dash} =
        TartarusEmu.Dashboard.start_link(state.dep.net, panels: [{DashboardPanel, arg}])

      {:ok, 200, body} = TartarusDashboard.http_get(TartarusDashboard.url(dash) <> "api/panels")

      assert %{"panels" => [%{"name" => "lats", "rows" => rows}]} = Tartarus.JSON.decode!(body)

      assert Enum.any?(rows, &(hd(&1) == "bearer"))
      TartarusDashboard.stop(dash)
    after
      Experiment.teardown(state)
    end
  end
end
