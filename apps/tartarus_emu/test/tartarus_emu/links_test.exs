defmodule TartarusEmu.LinksTest do
  # The emulator's transport: link latency and loss as Tartarus.connect/3's properties say.
  use ExUnit.Case, async: false

  alias TartarusEmu.Links

  defmodule Traveller do
    @moduledoc false
    use Tartarus.Agent

    def init(owner), do: {:stay, %{owner: owner}}

    def handle_message(:state, from, s) do
      Tartarus.Agent.reply(from, s)
      {:stay, s}
    end

    # Requests `msg` from `agent` and answers with the result and the time it took (ms).
    def handle_message({:timed, agent, msg}, from, s) do
      t0 = System.monotonic_time(:millisecond)
      result = Tartarus.request(agent, msg)
      Tartarus.Agent.reply(from, {result, System.monotonic_time(:millisecond) - t0})
      {:stay, s}
    end

    def handle_move_failed(dest, reason, _ctx, s) do
      send(s.owner, {:move_failed, dest, reason})
      {:stay, s}
    end
  end

  setup do
    Links.install()

    hosts =
      for _ <- 1..2 do
        {:ok, h} = Tartarus.start_host(:"links_#{System.unique_integer([:positive])}")
        on_exit(fn -> Tartarus.stop_host(h) end)
        h
      end

    %{hosts: hosts}
  end

  test "a link with loss 1.0 makes every move over it fail with :link_loss", %{hosts: [a, b]} do
    :ok = Tartarus.connect(a, b, loss: 1.0)
    {:ok, id} = Tartarus.create_mobile_agent(a, Traveller, self())

    for _ <- 1..5 do
      assert Tartarus.move({id, a}, b) == {:error, :link_loss}
      assert_receive {:move_failed, ^b, :link_loss}
    end

    assert Tartarus.whereis(id) == {:ok, a}
    # Connecting again replaces the link's properties.
    :ok = Tartarus.connect(a, b, loss: 0)
    assert Tartarus.move({id, a}, b) == :ok
    assert Tartarus.whereis(id) == {:ok, b}
  end

  test "a link's latency is paid by each message of a hand-off and by agents' messages both ways",
       %{hosts: [a, b]} do
    :ok = Tartarus.connect(a, b, latency_ms: 100)
    {:ok, id} = Tartarus.create_mobile_agent(a, Traveller, self())
    t0 = System.monotonic_time(:millisecond)
    assert Tartarus.move({id, a}, b) == :ok
    # prepare, prepared, commit: three one-way delays at least (a lower bound, not a timing)
    assert System.monotonic_time(:millisecond) - t0 >= 300

    {:ok, other} = Tartarus.create_mobile_agent(a, Traveller, self())
    assert {:ok, {{:ok, %{owner: _}}, ms}} = Tartarus.request(other, {:timed, id, :state})
    assert ms >= 200
  end

  test "the network installs it on the nodes of links with latency or loss, and only then" do
    refute Links.emulated?(latency_ms: 0, loss: 0.0)
    assert Links.emulated?(latency_ms: 3, loss: 0.0)
    assert Links.emulated?(%{latency_ms: 0, loss: 0.5})

    Tartarus.Transport.clear()
    TartarusEmu.EmuCase.start_network!(TartarusEmu.Topology.line(2))
    assert Tartarus.Transport.installed() == nil

    TartarusEmu.EmuCase.start_network!(TartarusEmu.Topology.line(2), link: [latency_ms: 3])
    assert Tartarus.Transport.installed() == Links
  end
end
