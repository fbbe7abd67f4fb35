defmodule DiagTmpTest do
  use Tartarus.HostCase, async: false

  test "diag" do
    h = host!()
    id = agent!(h, %{init_action: {:return, 42}}, owner: self())
    assert_receive {:tartarus_result, ^id, 42}
    Process.sleep(100)
    [%{pid: pid}] = Tartarus.agents(h) |> IO.inspect()
    IO.inspect(Process.alive?(pid))
    {:ok, hpid} = Tartarus.Host.whereis(h)
    IO.inspect(:sys.get_state(hpid).monitors)
    IO.inspect(Tartarus.status(h))
  end
end
