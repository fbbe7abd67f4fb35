defmodule TartarusWarehouse.RobotTest do
  use ExUnit.Case, async: true

  alias TartarusWarehouse.Robot

  defp db(s) do
    {:ok, db, _} = Robot.read(:db, s)
    db
  end

  test "database changes apply in the distributor's order, whatever order they arrive in" do
    {:ok, s} = Robot.init(robot: "r1")
    # The deletion (2nd change) arrives before the insertion (1st): it waits for it.
    {:ok, s} = Robot.write({:db, 2, {:delete, "X"}}, s)
    assert db(s) == %{inserts: %{}, deleted: MapSet.new(), version: 0, pending: [2]}

    {:ok, s} = Robot.write({:db, 1, {:insert, "T2", "X"}}, s)
    assert db(s) == %{inserts: %{}, deleted: MapSet.new(["X"]), version: 2, pending: []}

    # A change already applied (a sequence agent that came back) changes nothing.
    {:ok, s2} = Robot.write({:db, 1, {:insert, "T2", "X"}}, s)
    assert db(s2) == db(s)

    # In order: inserted, then deleted again.
    {:ok, s} = Robot.write({:db, 3, {:insert, "T1", "Y"}}, s)
    assert db(s).inserts == %{"T1" => "Y"}
  end

  test "a robot waiting for an inserted task goes on once the deletion is applied" do
    {:ok, s} = Robot.init(robot: "r1")
    s = %{s | state: {:inserted, "X", :free}}
    {:ok, s} = Robot.write({:db, 2, {:delete, "X"}}, s)
    # the deletion waits for change 1 ...
    assert s.state == {:inserted, "X", :free}
    {:ok, s} = Robot.write({:db, 1, {:insert, "T2", "X"}}, s)
    # ... then both apply, and the robot no longer waits for X's agent.
    assert s.state == :free
  end
end
