defmodule TartarusLats.TraceRepairTest do
  # Trace across a broken chain of motion vectors (issue 28, item 5): one test per kind of
  # break. The walk of the thesis's Appendix .2 (X: d -> e -> f -> i -> h, the door at d
  # only) is recorded by the nodes, then the tables in the host stores are broken the way a
  # lost hand-over, a dead node or a mislinked pair of vectors breaks them.
  use ExUnit.Case, async: false
  doctest TartarusLats.Query.Bridge

  alias TartarusLats.{Deployment, World}

  # The thesis's Appendix .2 (see test/support/appendix.ex).
  defp appendix_world, do: TartarusLats.Test.Appendix.world()

  setup_all do
    dep =
      Deployment.start(seed: 1, world: appendix_world(), prefix: "trace-repair")
      |> Deployment.run(150)

    on_exit(fn -> Deployment.stop(dep) end)
    %{dep: dep, tag: World.tag(dep.world, :x)}
  end

  defp nodes({:ok, %{path: path}}), do: Enum.map(path, & &1.node)

  defp stays(dep, node, tag),
    do: Tartarus.store_get(dep.hosts[node], {:lats, :mv}).tags |> Map.fetch!(tag)

  # Replaces the stays of `tag` at `node` by `fun.(stays)` in the host store, for the test.
  defp put_stays(dep, node, tag, fun) do
    mv = Tartarus.store_get(dep.hosts[node], {:lats, :mv})

    :ok =
      Tartarus.store_put(dep.hosts[node], {:lats, :mv}, %{
        mv
        | tags: %{mv.tags | tag => fun.(mv.tags[tag])}
      })
  end

  # Runs `fun` with the tables of every node as they were recorded restored afterwards.
  defp broken(dep, fun) do
    saved = Map.new(dep.hosts, fn {n, h} -> {n, Tartarus.store_get(h, {:lats, :mv})} end)

    try do
      fun.()
    after
      for {n, mv} <- saved, do: :ok = Tartarus.store_put(dep.hosts[n], {:lats, :mv}, mv)
    end
  end

  defp trace(dep, from, tag, opts \\ []),
    do: TartarusLats.query(dep.hosts[from], :trace, tag, [report: false] ++ opts)

  test "the recorded walk traces whole, with or without repair", %{dep: dep, tag: tag} do
    for repair <- [false, true] do
      assert {:ok, r} = trace(dep, :h, tag, repair: repair)
      assert nodes(r.answer) == [:d, :e, :f, :i, :h]
      assert r.complete and r.breaks == []
    end
  end

  test "a lost hand-over (e -> f: e's tag left to nobody, f's came from outside, f has no door)",
       %{dep: dep, tag: tag} do
    broken(dep, fn ->
      put_stays(dep, :e, tag, fn [s] -> [%{s | to: :infinity, to_arrived_at: nil}] end)
      put_stays(dep, :f, tag, fn [s] -> [%{s | from: :infinity, from_left_at: nil}] end)
      [%{arrived_at: f_arrived}] = stays(dep, :f, tag)
      [%{left_at: e_left}] = stays(dep, :e, tag)

      # Walking back from h: f's entry from outside is a gap.
      assert {:ok, plain} = trace(dep, :h, tag)
      assert {:ok, %{entry: :gap, status: :present}} = plain.answer
      assert nodes(plain.answer) == [:f, :i, :h]
      refute plain.complete
      assert [%{node: :f, kind: :entry, at: ^f_arrived, bridged_to: nil}] = plain.breaks

      assert {:ok, fixed} = trace(dep, :h, tag, repair: true)
      assert {:ok, %{entry: :infinity, status: :present}} = fixed.answer
      assert nodes(fixed.answer) == [:d, :e, :f, :i, :h]
      assert [%{node: :f, kind: :entry, bridged_to: :e, ring: 1}] = fixed.breaks
      assert fixed.complete

      # Fired at e: e's tag "left the building" from a node with no door. Without repair
      # the answer says where the chain broke instead of looking complete.
      assert {:ok, plain} = trace(dep, :e, tag)
      assert {:ok, %{status: :exited}} = plain.answer
      assert nodes(plain.answer) == [:d, :e]
      assert [%{node: :e, kind: :exit, at: ^e_left, bridged_to: nil}] = plain.breaks
      refute plain.complete

      assert {:ok, fixed} = trace(dep, :e, tag, repair: true)
      assert {:ok, %{entry: :infinity, status: :present}} = fixed.answer
      assert nodes(fixed.answer) == [:d, :e, :f, :i, :h]
      assert [%{node: :e, kind: :exit, bridged_to: :f, ring: 1}] = fixed.breaks
      assert fixed.complete
    end)
  end

  test "a gap: f recorded nothing (down while X walked through), e and i do not link",
       %{dep: dep, tag: tag} do
    broken(dep, fn ->
      put_stays(dep, :e, tag, fn [s] -> [%{s | to: :infinity, to_arrived_at: nil}] end)
      put_stays(dep, :f, tag, fn _ -> [] end)
      put_stays(dep, :i, tag, fn [s] -> [%{s | from: :infinity, from_left_at: nil}] end)

      assert {:ok, plain} = trace(dep, :h, tag)
      assert {:ok, %{entry: :gap}} = plain.answer
      assert nodes(plain.answer) == [:i, :h]
      assert [%{node: :i, kind: :entry, bridged_to: nil}] = plain.breaks

      # Bridged over two rings (e is not a neighbour of i); f is the one zone next to
      # both, so X passed through it unseen: it goes on the path, between e and i.
      assert {:ok, fixed} = trace(dep, :h, tag, repair: true)
      assert {:ok, %{entry: :infinity, status: :present, path: path}} = fixed.answer
      assert nodes(fixed.answer) == [:d, :e, :f, :i, :h]
      assert [%{node: :i, kind: :entry, bridged_to: :e, ring: 2, through: :f}] = fixed.breaks
      [_d, e, f, i, _h] = path
      assert f.arrived_at == e.left_at and f.left_at == i.arrived_at
      assert fixed.complete

      # With a second zone next to both e and i (a link e - j here), which one X passed is
      # unknown: the zone is left out and the answer is not complete.
      ej = Map.put(Tartarus.store_get(dep.hosts[:j], {:lats, :neighbours}), :e, dep.hosts[:e])
      je = Map.put(Tartarus.store_get(dep.hosts[:e], {:lats, :neighbours}), :j, dep.hosts[:j])
      :ok = Tartarus.store_put(dep.hosts[:j], {:lats, :neighbours}, ej)
      :ok = Tartarus.store_put(dep.hosts[:e], {:lats, :neighbours}, je)

      try do
        assert {:ok, r} = trace(dep, :h, tag, repair: true)
        assert nodes(r.answer) == [:d, :e, :i, :h]
        assert [%{node: :i, bridged_to: :e, ring: 2, through: nil}] = r.breaks
        refute r.complete
      after
        :ok = Tartarus.store_put(dep.hosts[:j], {:lats, :neighbours}, Map.delete(ej, :e))
        :ok = Tartarus.store_put(dep.hosts[:e], {:lats, :neighbours}, Map.delete(je, :j))
      end
    end)
  end

  test "a gap nobody around can bridge: the break stands, named, never complete",
       %{dep: dep, tag: tag} do
    broken(dep, fn ->
      put_stays(dep, :d, tag, fn _ -> [] end)
      put_stays(dep, :e, tag, fn _ -> [] end)
      put_stays(dep, :f, tag, fn [s] -> [%{s | from: :infinity, from_left_at: nil}] end)

      assert {:ok, r} = trace(dep, :h, tag, repair: true)
      assert {:ok, %{entry: :gap, status: :present}} = r.answer
      assert nodes(r.answer) == [:f, :i, :h]
      assert [%{node: :f, kind: :entry, bridged_to: nil}] = r.breaks
      refute r.complete
      # It asked f itself, its neighbours and theirs before answering.
      assert MapSet.subset?(MapSet.new([:e, :g, :i, :d, :h, :j]), MapSet.new(r.route))
    end)
  end

  test "an inconsistent pair: an MVF with no matching MVB, an MVB with no matching MVF",
       %{dep: dep, tag: tag} do
    broken(dep, fn ->
      # f saw X arrive 2 s later than e was told (e's MVF points to a stay f does not have).
      put_stays(dep, :f, tag, fn [s] -> [%{s | arrived_at: s.arrived_at + 2}] end)

      # Fired at e: forward from e to f finds no stay arriving when e's MVF says.
      assert {:ok, plain} = trace(dep, :e, tag)
      assert {:ok, %{status: :broken}} = plain.answer
      assert nodes(plain.answer) == [:d, :e]
      assert [%{node: :f, kind: :forward_link, bridged_to: nil}] = plain.breaks

      assert {:ok, fixed} = trace(dep, :e, tag, repair: true)
      assert {:ok, %{status: :present}} = fixed.answer
      assert nodes(fixed.answer) == [:d, :e, :f, :i, :h]
      assert [%{node: :f, kind: :forward_link, bridged_to: :f, ring: 0}] = fixed.breaks
      assert fixed.complete
    end)

    broken(dep, fn ->
      # i's MVB says X left f at a time no stay of f ended.
      put_stays(dep, :i, tag, fn [s] -> [%{s | from_left_at: s.from_left_at - 3}] end)

      assert {:ok, plain} = trace(dep, :h, tag)
      assert {:ok, %{status: :broken}} = plain.answer
      assert [%{node: :f, kind: :back_link, bridged_to: nil}] = plain.breaks
      refute plain.complete

      assert {:ok, fixed} = trace(dep, :h, tag, repair: true)
      assert {:ok, %{entry: :infinity, status: :present}} = fixed.answer
      assert nodes(fixed.answer) == [:d, :e, :f, :i, :h]
      assert [%{node: :f, kind: :back_link, bridged_to: :f, ring: 0}] = fixed.breaks
      assert fixed.complete
    end)
  end
end
