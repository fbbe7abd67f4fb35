defmodule TartarusLats.MotionVectorsTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.MotionVectors

  alias TartarusLats.MotionVectors, as: MV

  @x {"12121212b64445208f0c720eaf059935", 1, 1}

  # Thesis Appendix .2, Figure 1: ten nodes a..j on one floor.
  @adjacency %{
    a: [:b, :c, :d],
    b: [:a],
    c: [:a, :g],
    d: [:a, :e],
    e: [:d, :f],
    f: [:e, :g, :i],
    g: [:c, :f],
    h: [:i],
    i: [:f, :h, :j],
    j: [:i]
  }

  defp network(timeout \\ 15),
    do: Map.new(@adjacency, fn {n, _} -> {n, MV.new(n, timeout: timeout)} end)

  # Delivers an event to a node and every resulting message, instantly.
  defp event(net, node, now, ev), do: deliver(net, now, [{node, ev}])

  defp deliver(net, _now, []), do: net

  defp deliver(net, now, [{node, ev} | queue]) do
    {mv, actions} = MV.handle(Map.fetch!(net, node), now, ev)

    out =
      Enum.flat_map(actions, fn
        {:broadcast, msg} -> for n <- Map.fetch!(@adjacency, node), do: {n, msg}
        {:send, to, msg} -> [{to, msg}]
      end)

    deliver(Map.put(net, node, mv), now, queue ++ out)
  end

  defp tick(net, now), do: Map.new(net, fn {n, mv} -> {n, elem(MV.handle(mv, now, :tick), 0)} end)

  defp ticks(net, from, to), do: Enum.reduce(from..to, net, &tick(&2, &1))

  # X walks d -> e -> f -> i -> h; zones overlap, so sometimes the next node
  # sees X before the previous one lets go, sometimes after.
  defp appendix_walk do
    network()
    |> event(:d, 0, {:entered_zone, @x, 0})
    |> ticks(1, 20)
    |> event(:d, 30, {:left_zone, @x, 30})
    |> event(:e, 31, {:entered_zone, @x, 31})
    |> event(:f, 58, {:entered_zone, @x, 58})
    |> event(:e, 60, {:left_zone, @x, 60})
    |> event(:f, 90, {:left_zone, @x, 90})
    |> ticks(91, 92)
    |> event(:i, 93, {:entered_zone, @x, 93})
    |> event(:h, 121, {:entered_zone, @x, 121})
    |> event(:i, 122, {:left_zone, @x, 122})
    |> ticks(123, 150)
  end

  test "Appendix .2: the handshakes build the thesis's motion vectors" do
    net = appendix_walk()
    vectors = Map.new(net, fn {n, mv} -> {n, {MV.mvb(mv, @x), MV.mvf(mv, @x)}} end)

    assert vectors == %{
             a: {nil, nil},
             b: {nil, nil},
             c: {nil, nil},
             g: {nil, nil},
             j: {nil, nil},
             d: {{:infinity, :d}, {:d, :e}},
             e: {{:d, :e}, {:e, :f}},
             f: {{:e, :f}, {:f, :i}},
             i: {{:f, :i}, {:i, :h}},
             h: {{:i, :h}, {:h, :h}}
           }
  end

  test "Appendix .2: MVB back and MVF forward from any node of the path give d, e, f, i, h" do
    net = appendix_walk()

    for start <- [:d, :e, :f, :i, :h] do
      assert {:ok, trace} = MV.trace(net, start, @x)
      assert Enum.map(trace.path, & &1.node) == [:d, :e, :f, :i, :h]
      assert trace.entry == :infinity
      assert trace.status == :present
    end

    assert {:ok, %{path: path}} = MV.trace(net, :e, @x)

    assert path == [
             %{node: :d, arrived_at: 0, left_at: 30},
             %{node: :e, arrived_at: 31, left_at: 60},
             %{node: :f, arrived_at: 58, left_at: 90},
             %{node: :i, arrived_at: 93, left_at: 122},
             %{node: :h, arrived_at: 121, left_at: nil}
           ]

    for start <- [:a, :b, :j] do
      assert MV.trace(net, start, @x) == {:error, :no_trace}
    end
  end

  test "Appendix .2: a Where-is agent following MVF from d reaches h" do
    net = appendix_walk()

    follow = fn follow, node, hops ->
      case MV.mvf(net[node], @x) do
        {^node, ^node} -> {node, hops}
        {^node, next} when is_atom(next) -> follow.(follow, next, [node | hops])
      end
    end

    assert {:h, hops} = follow.(follow, :d, [])
    assert Enum.reverse(hops) == [:d, :e, :f, :i]
  end

  test "a neighbour that never acknowledges: the exit is INFINITY after the timeout" do
    net = appendix_walk() |> event(:h, 200, {:left_zone, @x, 200})
    assert MV.mvf(net.h, @x) == {:h, :pending}
    net = ticks(net, 201, 214)
    assert MV.mvf(net.h, @x) == {:h, :pending}
    net = tick(net, 215)
    assert MV.mvf(net.h, @x) == {:h, :infinity}
    assert {:ok, %{status: :exited, entry: :infinity}} = MV.trace(net, :d, @x)
    # the notice i heard expires too
    assert net.i.notices == %{}
  end

  test "a late acknowledgement replaces INFINITY" do
    {h, []} = MV.handle(MV.new(:h), 121, {:entered_zone, @x, 121})
    {h, [{:broadcast, {:leaving, @x, :h, 200, 121}}]} = MV.handle(h, 200, {:left_zone, @x, 200})
    {h, []} = MV.handle(h, 216, :tick)
    assert MV.mvf(h, @x) == {:h, :infinity}
    {h, []} = MV.handle(h, 217, {:ack, @x, :i, 200, 214})
    assert MV.mvf(h, @x) == {:h, :i}
  end

  test "an arrival nobody announces is an entry into the building" do
    {p, []} = MV.handle(MV.new(:p1), 10, {:entered_zone, @x, 10})
    assert MV.mvb(p, @x) == {:pending, :p1}
    {p, []} = MV.handle(p, 24, :tick)
    assert MV.mvb(p, @x) == {:pending, :p1}
    {p, []} = MV.handle(p, 25, :tick)
    assert MV.mvb(p, @x) == {:infinity, :p1}
    # a late notice while the tag is still here corrects it
    {p, [{:send, :p2, {:ack, @x, :p1, 9, 10}}]} = MV.handle(p, 26, {:leaving, @x, :p2, 9, 3})
    assert MV.mvb(p, @x) == {:p2, :p1}
  end

  test "a tag that steps out and back before anyone sees it loops at the same node" do
    net =
      network()
      |> event(:d, 0, {:entered_zone, @x, 0})
      |> event(:d, 10, {:left_zone, @x, 10})
      |> event(:d, 14, {:entered_zone, @x, 14})
      |> ticks(15, 40)

    assert MV.mvf(net.d, @x) == {:d, :d}
    assert MV.mvb(net.d, @x) == {:d, :d}
    assert length(MV.segments(net.d, @x)) == 2

    assert {:ok, %{path: [%{node: :d, arrived_at: 0, left_at: nil}], status: :present}} =
             MV.trace(net, :d, @x)
  end

  test "a neighbour that had the tag all along does not acknowledge an overlap" do
    net =
      network()
      |> event(:e, 0, {:entered_zone, @x, 0})
      |> event(:d, 5, {:entered_zone, @x, 5})
      |> event(:d, 8, {:left_zone, @x, 8})

    assert MV.mvf(net.e, @x) == {:e, :e}
    assert MV.mvf(net.d, @x) == {:d, :pending}
    assert MV.mvb(net.e, @x) == {:pending, :e}
  end

  test "a notice heard before the tag arrives is used when it arrives, and expires otherwise" do
    {e, []} = MV.handle(MV.new(:e), 30, {:leaving, @x, :d, 30, 0})
    {e2, [{:send, :d, {:ack, @x, :e, 30, 40}}]} = MV.handle(e, 40, {:entered_zone, @x, 40})
    assert MV.mvb(e2, @x) == {:d, :e}

    {e3, []} = MV.handle(e, 45, :tick)
    {e3, []} = MV.handle(e3, 46, {:entered_zone, @x, 46})
    assert MV.mvb(e3, @x) == {:pending, :e}
  end

  test "stale acks and unknown events" do
    {d, _} = MV.handle(MV.new(:d), 0, {:entered_zone, @x, 0})
    assert {^d, []} = MV.handle(d, 1, {:ack, @x, :e, 99, 100})
    assert_raise ArgumentError, ~r/invalid event/, fn -> MV.handle(d, 1, {:bogus}) end
  end

  test "prune drops old closed stays" do
    net = appendix_walk()
    d = MV.prune(net.d, 100)
    assert MV.segments(d, @x) == []
    assert {:ok, %{entry: :broken}} = MV.trace(Map.put(net, :d, d), :h, @x)
  end
end
