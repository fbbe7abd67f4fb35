defmodule Tartarus.Migration.GonePointersTest do
  # Forwarding pointers of an agent that ended are reclaimed on the hosts it visited, so a
  # host's table does not grow with the agents that passed through it; a message to the
  # ended agent gets {:error, :not_found}, never a hang.
  use Tartarus.HostCase, async: false

  alias Tartarus.Test.Probe

  defp pointers(host) do
    {:ok, info} = Tartarus.Host.local(host)
    for {key, _dest, _state} <- Tartarus.Ledger.pointers(info), do: key
  end

  test "an agent that stops leaves no forwarding pointer on the hosts it visited" do
    [a, b, c] = line!(3)
    {:ok, id} = Tartarus.create_mobile_agent(a, Probe, %{test: self()}, name: "wanderer")
    :ok = Tartarus.move({id, a}, b)
    :ok = Tartarus.move({id, b}, c)
    :ok = Tartarus.move({id, c}, b)
    assert pointers(a) |> Enum.sort() == Enum.sort([id, "wanderer"])
    assert pointers(c) |> Enum.sort() == Enum.sort([id, "wanderer"])

    :ok = Tartarus.post({id, a}, {:do, {:stop, :done}})
    assert eventually(fn -> pointers(a) == [] and pointers(c) == [] end)
    assert pointers(b) == []
    assert Tartarus.post({id, a}, :inc) == {:error, :not_found}
  end

  test "a live agent keeps its pointers; a forged notice for another agent changes nothing" do
    [a, b] = line!(2)
    {:ok, id} = Tartarus.create_mobile_agent(a, Probe, %{test: self()})
    :ok = Tartarus.move({id, a}, b)
    send(Tartarus.Host.Directory, {:"$tartarus_gone", a, "0000000000000000", nil})
    send(Tartarus.Host.Directory, {:"$tartarus_gone", a, :not_an_id, 3})
    :sys.get_state(Tartarus.Host.Directory)
    {:ok, server} = Tartarus.Host.whereis(a)
    :sys.get_state(server)
    assert id in pointers(a)
    assert :ok = Tartarus.post({id, a}, :inc)
  end

  test "an agent killed where it lives leaves no pointer on the hosts it visited either" do
    [a, b, c] = line!(3)
    {:ok, id} = Tartarus.create_mobile_agent(a, Probe, %{test: self()}, name: "victim")
    :ok = Tartarus.move({id, a}, b)
    :ok = Tartarus.move({id, b}, c)
    assert pointers(a) |> Enum.sort() == Enum.sort([id, "victim"])

    :ok = Tartarus.kill({id, c})
    assert eventually(fn -> pointers(a) == [] and pointers(b) == [] end)
    assert Tartarus.post({id, a}, :inc) == {:error, :not_found}
  end
end
