defmodule TartarusEmu.TopologyTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.Topology

  doctest Topology

  defp degrees(topo), do: topo |> Topology.adjacency() |> Map.values() |> Enum.map(&length/1)

  describe "builders" do
    test "line" do
      topo = Topology.line(6)
      assert topo.nodes == [:h1, :h2, :h3, :h4, :h5, :h6]
      assert Topology.edge_count(topo) == 5
      assert Enum.frequencies(degrees(topo)) == %{1 => 2, 2 => 4}
      assert Topology.connected?(topo)
      assert Topology.diameter(topo) == 5
      assert Topology.line(1) |> Topology.diameter() == 0
      assert topo.kind == :line
    end

    test "ring" do
      topo = Topology.ring(7)
      assert Topology.size(topo) == 7
      assert Topology.edge_count(topo) == 7
      assert Enum.all?(degrees(topo), &(&1 == 2))
      assert Topology.diameter(topo) == 3
      assert Enum.all?(topo.edges, fn {a, b} -> a < b end)

      assert_raise ArgumentError, "Topology.ring: expected an integer >= 3, got: 2", fn ->
        Topology.ring(2)
      end
    end

    test "grid" do
      topo = Topology.grid(3, 4)
      assert Topology.size(topo) == 12
      assert Topology.edge_count(topo) == 3 * 3 + 2 * 4
      assert Enum.frequencies(degrees(topo)) == %{2 => 4, 3 => 6, 4 => 2}
      assert Topology.diameter(topo) == 2 + 3
      assert topo.positions[:h12] == {3.0, 2.0}
      assert Topology.grid(1, 1) |> Topology.edge_count() == 0

      assert_raise ArgumentError, ~r/expected an integer >= 1, got: 0/, fn ->
        Topology.grid(0, 3)
      end
    end

    test "random geometric is deterministic by seed and leaves the global seed alone" do
      :rand.seed(:exsss, 1)
      before = :rand.export_seed()

      a = Topology.random_geometric(40, 0.25, 42)
      assert a == Topology.random_geometric(40, 0.25, 42)
      assert a != Topology.random_geometric(40, 0.25, 43)
      assert :rand.export_seed() == before

      assert Topology.size(a) == 40

      for {n, {x, y}} <- a.positions do
        assert n in a.nodes
        assert x >= 0 and x < 1 and y >= 0 and y < 1
      end

      for {p, q} <- a.edges do
        {xp, yp} = a.positions[p]
        {xq, yq} = a.positions[q]
        assert :math.sqrt(:math.pow(xp - xq, 2) + :math.pow(yp - yq, 2)) <= 0.25
      end
    end

    test "random geometric retries until connected, or says why it cannot" do
      for seed <- 1..5 do
        assert Topology.random_geometric(30, 0.3, seed, connected: true) |> Topology.connected?()
      end

      assert Topology.random_geometric(10, 0.0, 1) |> Topology.edge_count() == 0

      assert_raise ArgumentError,
                   ~r/no connected graph of 10 nodes with radius 0.0 in 3 attempts/,
                   fn ->
                     Topology.random_geometric(10, 0.0, 1, connected: true, max_attempts: 3)
                   end

      assert Topology.random_geometric(3, 2, :rand.seed_s(:exsss, 5)) |> Topology.edge_count() ==
               3
    end
  end

  describe "new/3 and queries" do
    test "validates input" do
      assert_raise ArgumentError, ~r/duplicates: \[:a\]/, fn -> Topology.new([:a, :a], []) end

      assert_raise ArgumentError, ~r/self-loops, got: {:a, :a}/, fn ->
        Topology.new([:a], [{:a, :a}])
      end

      assert_raise ArgumentError, ~r/between listed nodes, got: {:a, :z}/, fn ->
        Topology.new([:a], [{:a, :z}])
      end
    end

    test "disconnected graphs and distances" do
      topo = Topology.new([:a, :b, :c, :d], [{:a, :b}, {:c, :d}])
      refute Topology.connected?(topo)
      assert Topology.diameter(topo) == :infinity
      assert Topology.distances(topo, :a) == %{a: 0, b: 1}
      assert Topology.distances(topo, :zz) == %{}
      assert Topology.neighbours(topo, :zz) == []
      assert Topology.connected?(Topology.new([], []))
      assert Topology.diameter(Topology.new([], [])) == 0
    end

    test "links keep attributes under normalised keys" do
      topo = Topology.new([:a, :b], [{:a, :b}], links: %{{:b, :a} => %{loss: 0.5}})
      assert Topology.fetch_link(topo, :a, :b) == {:ok, %{latency_ms: 0, loss: 0.5}}
    end
  end

  describe "parse/2" do
    @plan """
    # Lab floor plan
    floor 1
    node lobby 0 0        # entrance
    node lab-1 4.5 0
    floor 2
    node office 1 2
    node roof.top floor 9
    node store

    edge lobby lab-1 latency_ms=12 loss=0.05
    edge lab-1 office
    edge office store latency_ms=1.5
    edge roof.top store
    """

    test "a full floor plan" do
      assert {:ok, topo} = Topology.parse(@plan)
      assert topo.kind == :file
      assert topo.nodes == ["lobby", "lab-1", "office", "roof.top", "store"]

      assert topo.positions == %{
               "lobby" => {0.0, 0.0},
               "lab-1" => {4.5, 0.0},
               "office" => {1.0, 2.0}
             }

      assert topo.floors == %{
               "lobby" => 1,
               "lab-1" => 1,
               "office" => 2,
               "roof.top" => 9,
               "store" => 2
             }

      assert Topology.fetch_link(topo, "lab-1", "lobby") == {:ok, %{latency_ms: 12, loss: 0.05}}
      assert Topology.fetch_link(topo, "office", "store") == {:ok, %{latency_ms: 1.5, loss: 0.0}}
      assert Topology.connected?(topo)
      assert Topology.diameter(topo) == 4
    end

    test "edges may name nodes declared later; CRLF line ends work" do
      assert {:ok, topo} = Topology.parse("edge a b\r\nnode a\r\nnode b\r\n")
      assert topo.edges == MapSet.new([{"a", "b"}])
    end

    test "never creates atoms from file contents; an explicit mapping is used when given" do
      name = "node_name_that_is_not_an_atom_#{System.unique_integer([:positive])}"
      assert {:ok, topo} = Topology.parse("node #{name}\n")
      assert topo.nodes == [name]
      assert_raise ArgumentError, fn -> String.to_existing_atom(name) end

      assert {:ok, topo} =
               Topology.parse("node a\nnode b\nedge b a\n", names: %{"a" => :h1, "b" => :h2})

      assert topo.edges == MapSet.new([{:h1, :h2}])

      assert Topology.parse("node a\nnode c\n", names: %{"a" => :h1}) ==
               {:error, "line 2: node \"c\" is not in the :names mapping"}

      assert_raise ArgumentError, ~r/expected :names to be a map/, fn ->
        Topology.parse("", names: [:a])
      end
    end

    test "round trip through to_text/1" do
      assert {:ok, topo} = Topology.parse(@plan)
      assert Topology.parse(Topology.to_text(topo)) == {:ok, topo}

      grid = Topology.grid(3, 3)
      names = Map.new(grid.nodes, &{Atom.to_string(&1), &1})
      assert {:ok, back} = Topology.parse(Topology.to_text(grid), names: names)
      assert %{back | kind: :grid} == grid
    end

    test "malformed input names the line" do
      cases = [
        {"node a\nnode a\n", "line 2: duplicate node \"a\""},
        {"node a\n\n\nedge a b\n", "line 4: edge to undeclared node \"b\""},
        {"node a\nedge a a\n",
         "line 2: expected an edge between two different nodes, got a self-loop on \"a\""},
        {"node a\nnode b\nedge a b\nedge b a\n",
         "line 4: duplicate edge between \"b\" and \"a\""},
        {"node a x 1\n", "line 1: expected a number for x coordinate, got: \"x\""},
        {"node a 1\n",
         "line 1: expected \"[X Y [Z]] [floor F] [zone Z]\" after the node name, got: \"1\""},
        {"node a floor 1.5\n", "line 1: expected an integer floor, got: \"1.5\""},
        {"floor\n", "line 1: expected \"floor F\" with one integer, got: \"\""},
        {"node a 1 2 3 4\n",
         "line 1: expected \"[X Y [Z]] [floor F] [zone Z]\" after the node name, got: \"1 2 3 4\""},
        {"node a zone x zone y\n", "line 1: zone given twice"},
        {"node\n",
         "line 1: expected \"node NAME [X Y [Z]] [floor F] [zone Z]\", got too few arguments"},
        {"edge a\n", "line 1: expected \"edge A B [attr=value ...]\", got too few arguments"},
        {"link a b\n",
         "line 1: unknown directive \"link\": expected \"node\", \"edge\" or \"floor\""},
        {"node a\nnode b\nedge a b speed=3\n",
         "line 3: unknown edge attribute \"speed=3\": expected latency_ms=N or loss=P"},
        {"node a\nnode b\nedge a b loss=1.5\n",
         "line 3: expected loss between 0 and 1, got: 1.5"},
        {"node a\nnode b\nedge a b latency_ms=-1\n", "line 3: expected latency_ms >= 0, got: -1"},
        {"node a\nnode b\nedge a b loss=0.1 loss=0.2\n", "line 3: attribute loss given twice"},
        {"node a/b\n",
         "line 1: expected a node name of 1 to 64 characters from A-Z a-z 0-9 _ - . :, got: \"a/b\""}
      ]

      for {text, error} <- cases do
        assert Topology.parse(text) == {:error, error}
      end
    end

    test "3-D positions and zones are parsed and written back" do
      text = "node a 0 0 4 floor 1 zone lab\nnode b 9 0 zone lab\nedge a b\n"
      assert {:ok, topo} = Topology.parse(text)
      assert topo.positions == %{"a" => {0.0, 0.0, 4.0}, "b" => {9.0, 0.0}}
      assert topo.floors == %{"a" => 1}
      assert topo.zones == %{"a" => "lab", "b" => "lab"}
      assert {:ok, again} = Topology.parse(Topology.to_text(topo))

      assert {again.positions, again.floors, again.zones} ==
               {topo.positions, topo.floors, topo.zones}
    end

    test "from_file/2" do
      dir = Path.join(System.tmp_dir!(), "topology_test_#{System.unique_integer([:positive])}")
      File.mkdir_p!(dir)
      path = Path.join(dir, "plan.txt")

      try do
        File.write!(path, @plan)
        assert {:ok, %Topology{kind: :file}} = Topology.from_file(path)

        File.write!(path, "node a\nbogus\n")

        assert Topology.from_file(path) ==
                 {:error,
                  "#{path}: line 2: unknown directive \"bogus\": expected \"node\", \"edge\" or \"floor\""}

        assert {:error, "cannot read topology file " <> rest} =
                 Topology.from_file(Path.join(dir, "missing"))

        assert rest =~ "no such file"
      after
        File.rm_rf!(dir)
      end
    end

    test "property: garbage lines never crash the parser" do
      word =
        :proper_types.oneof([
          :proper_types.elements(
            ~w(node edge floor a b c 1 -2 3.5 x latency_ms=3 loss=0.5 loss=7 # =)
          ),
          :proper_types.list(:proper_types.integer(0, 255))
        ])

      line = :proper_types.list(word)
      doc = :proper_types.list(line)

      property =
        :proper.forall(doc, fn lines ->
          try do
            text =
              Enum.map_join(lines, "\n", fn words ->
                Enum.map_join(words, " ", fn
                  w when is_list(w) -> :erlang.list_to_binary(w)
                  w -> w
                end)
              end)

            case Topology.parse(text) do
              {:ok, %Topology{}} -> true
              {:error, "line " <> _} -> true
              _ -> false
            end
          rescue
            _ -> false
          end
        end)

      result = :proper.quickcheck(property, [:long_result, :quiet, {:numtests, 500}])
      assert result == true, "counterexample: #{inspect(result, charlists: :as_lists)}"
    end
  end
end
