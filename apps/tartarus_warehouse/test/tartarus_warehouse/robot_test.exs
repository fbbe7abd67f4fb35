defmodule TartarusWarehouse.RobotTest do
  use ExUnit.Case, async: true

  alias TartarusWarehouse.Robot

  defp db(s) do
    {:ok, db, _} = Robot.read(:db, s)
    db
  end

  @insert {1, {:insert, "T2", "X"}}
  @delete {2, {:delete, "X"}}

  test "database changes apply in the distributor's order, whichever agent comes first" do
    {:ok, s} = Robot.init(robot: "r1")
    # The deletion's agent (it carries changes 1 and 2) comes before the insertion's.
    {:ok, s} = Robot.write({:db, [@insert, @delete]}, s)
    assert db(s) == %{inserts: %{}, deleted: MapSet.new(["X"]), version: 2}

    # The insertion's agent comes later: nothing it carries is new.
    {:ok, s2} = Robot.write({:db, [@insert]}, s)
    assert db(s2) == db(s)

    # A third change: only it applies.
    {:ok, s} = Robot.write({:db, [@insert, @delete, {3, {:insert, "T1", "Y"}}]}, s)
    assert db(s) == %{inserts: %{"T1" => "Y"}, deleted: MapSet.new(["X"]), version: 3}
  end

  test "a change whose agent was lost is applied from the next agent" do
    {:ok, s} = Robot.init(robot: "r1")
    {:ok, s} = Robot.write({:db, [@insert]}, s)
    assert db(s).inserts == %{"T2" => "X"}
    # change 2 never came on its own; change 3's agent carries it
    {:ok, s} = Robot.write({:db, [@insert, @delete, {3, {:delete, "T3"}}]}, s)
    assert db(s) == %{inserts: %{}, deleted: MapSet.new(["X", "T3"]), version: 3}
  end

  test "a robot waiting for an inserted task goes on once its deletion is applied" do
    {:ok, s} = Robot.init(robot: "r1")
    {:ok, s} = Robot.write({:db, [@insert]}, s)
    s = %{s | state: {:inserted, "X", :free}}
    {:ok, s} = Robot.write({:db, [@insert, @delete]}, s)
    assert s.state == :free
  end
end
