defmodule Tartarus.Clock.VirtualTest do
  # The virtual clock moves time only when the VM is idle. A process whose heap is large is
  # collected on a dirty CPU scheduler: it is then in no run queue and a yield does not let
  # it through, yet it is not idle. Time must not jump while it computes.
  use ExUnit.Case, async: false

  alias Tartarus.Clock

  # A computation of a few hundred ms of CPU on a heap of several MB (its collections are
  # dirty), then the virtual time it ended at.
  defp crunch(owner) do
    spawn_link(fn ->
      list = Enum.shuffle(1..200_000)
      for _ <- 1..4, do: Enum.sort(list, &(&1 >= &2))
      send(owner, {:done, Clock.monotonic_time(:microsecond)})
    end)
  end

  test "time stands still while a process with a large heap computes" do
    Clock.Virtual.run([seed: 3], fn ->
      t0 = Clock.monotonic_time(:microsecond)
      Clock.send_after(self(), :tick, 1)
      crunch(self())

      assert_receive {:done, t}, 60_000
      # The computation cost no virtual time, and the timer fired after it, not during it.
      assert t == t0
      assert_receive :tick, 5_000
      assert Clock.monotonic_time(:microsecond) == t0 + 1_000
    end)
  end

  test "the idle readings agree with every process's status (strict mode refutes none)" do
    Clock.Virtual.run([seed: 4, strict: true], fn ->
      for i <- 1..3 do
        Clock.send_after(self(), {:tick, i}, i)
        crunch(self())
        assert_receive {:done, _}, 60_000
        assert_receive {:tick, ^i}, 5_000
      end

      assert %{false_idles: 0, fired: 3} = Clock.Virtual.stats()
    end)
  end
end
