defmodule Tartarus.BroadcastTest do
  # Neighbour broadcast: who receives, and the counts (per message and per byte) that let
  # sharing by broadcast be compared with sharing by agents.
  use Tartarus.HostCase, async: false

  alias Tartarus.Events

  doctest Tartarus.Broadcast

  defmodule Listener do
    @moduledoc false
    # Subscribes to broadcasts on every host it arrives at and forwards them to the test.
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(test) do
      :ok = A.subscribe_broadcasts()
      {:stay, test}
    end

    @impl true
    def handle_arrival(_ctx, test) do
      :ok = A.subscribe_broadcasts()
      send(test, {:subscribed, A.id(), A.host()})
      {:stay, test}
    end

    @impl true
    def handle_message({:broadcast, msg}, from, test) do
      A.reply(from, A.broadcast(msg))
      {:stay, test}
    end

    @impl true
    def handle_info({:tartarus_broadcast, from, msg}, test) do
      send(test, {:heard, A.id(), A.host(), from, msg})
      {:stay, test}
    end
  end

  defp counts(host), do: Tartarus.status(host).counts

  # A star: `hub` linked to each of `leaves`.
  defp star!(n) do
    [hub | leaves] = hosts!(n + 1)
    for l <- leaves, do: :ok = Tartarus.connect(hub, l)
    {hub, leaves}
  end

  test "one message to every neighbour, counted per message and per byte like migrations" do
    {hub, leaves} = star!(3)
    for l <- leaves, do: :ok = Tartarus.Broadcast.subscribe(l)
    Events.subscribe()
    msg = {:antibody, Enum.to_list(1..50)}

    assert Tartarus.broadcast(hub, msg) == {:ok, 3}

    for _ <- leaves do
      hub_addr = addr(hub)
      assert_receive {:tartarus_broadcast, ^hub_addr, ^msg}, 2_000
    end

    # The sender's counters: one broadcast, three messages, the bytes of the three.
    wire = fn to -> :erlang.external_size({:"$tartarus_broadcast", addr(to), addr(hub), msg}) end
    expected_bytes = leaves |> Enum.map(wire) |> Enum.sum()
    c = counts(hub)
    assert {c.broadcasts, c.broadcast_messages, c.broadcast_bytes} == {1, 3, expected_bytes}
    # One event for the broadcast, with the same figures.
    hub_addr = addr(hub)

    assert_receive {:tartarus_event,
                    %{type: :broadcast, host: ^hub_addr, messages: 3, bytes: ^expected_bytes} =
                      event},
                   2_000

    assert Enum.sort(event.to) == Enum.sort(Enum.map(leaves, &addr/1))

    # Each receiver counts one received broadcast.
    for l <- leaves do
      assert eventually(fn -> counts(l).broadcasts_received == 1 end)
      assert counts(l).broadcasts == 0
    end

    Events.unsubscribe()
  end

  test "a broadcast reaches neighbours only, not the sender's host nor two hops away" do
    [a, b, c] = line!(3)
    for h <- [a, b, c], do: :ok = Tartarus.Broadcast.subscribe(h)
    assert Tartarus.broadcast(a, :hello) == {:ok, 1}
    a_addr = addr(a)
    assert_receive {:tartarus_broadcast, ^a_addr, :hello}, 2_000
    # The one message above was b's; a and c heard nothing.
    :ok = Tartarus.Signal.settle()
    refute_received {:tartarus_broadcast, _, _}
    assert counts(b).broadcasts_received == 1
    assert counts(a).broadcasts_received == 0
    assert counts(c).broadcasts_received == 0
  end

  test "subscribed agents hear broadcasts; an agent's broadcast goes from its host" do
    [a, b, c] = line!(3)
    {:ok, on_a} = Tartarus.create_mobile_agent(a, Listener, self())
    {:ok, on_c} = Tartarus.create_mobile_agent(c, Listener, self())
    # An agent that did not subscribe hears nothing (and is not disturbed).
    deaf = agent!(a)
    {:ok, speaker} = Tartarus.create_mobile_agent(b, Listener, self())

    assert Tartarus.request({speaker, b}, {:broadcast, :news}) == {:ok, 2}
    b_addr = addr(b)
    assert_receive {:heard, ^on_a, _, ^b_addr, :news}, 2_000
    assert_receive {:heard, ^on_c, _, ^b_addr, :news}, 2_000
    refute_received {:heard, ^speaker, _, _, _}
    assert counts(b).broadcasts == 1
    assert counts(b).broadcast_messages == 2
    assert probe_state({deaf, a}).count == 0

    # The subscription follows the agent (it subscribes again on arrival).
    :ok = Tartarus.move({on_a, a}, c)
    # The move returns once the copy at c is committed; its arrival callback (which
    # subscribes) may run a moment later.
    c_addr = addr(c)
    assert_receive {:subscribed, ^on_a, ^c_addr}, 2_000
    assert Tartarus.broadcast(b, :later) == {:ok, 2}
    assert_receive {:heard, ^on_a, at, ^b_addr, :later}, 2_000
    assert at == addr(c)
    # The copy that left `a` ended; the overlay forgets its subscription when it sees that
    # process go (a monitor's message, on a busy machine a moment later).
    assert eventually(fn -> Tartarus.Broadcast.subscribers(a) == [] end)

    for id <- [on_a, on_c, deaf, speaker], do: Tartarus.kill(id)
  end

  test "unsubscribe, dead subscribers and bad messages" do
    [a, b] = line!(2)
    :ok = Tartarus.Broadcast.subscribe(b)
    :ok = Tartarus.Broadcast.subscribe(b)
    assert Tartarus.Broadcast.subscribers(b) == [self()]
    :ok = Tartarus.Broadcast.unsubscribe(b)
    assert Tartarus.Broadcast.subscribers(b) == []

    pid = spawn(fn -> receive do: (:never -> :ok) end)
    :ok = Tartarus.Broadcast.subscribe(b, pid)
    Process.exit(pid, :kill)
    assert eventually(fn -> Tartarus.Broadcast.subscribers(b) == [] end)

    assert {:error, {:not_portable, :fun, _}} = Tartarus.broadcast(a, fn -> 1 end)

    assert Tartarus.broadcast(:nowhere_host, :x) ==
             {:error, {:unknown_host, {:nowhere_host, node()}}}

    assert counts(a).broadcasts == 0
  end

  test "a host without neighbours broadcasts to nobody, and still counts the broadcast" do
    h = host!()
    assert Tartarus.broadcast(h, :alone) == {:ok, 0}
    c = counts(h)
    assert {c.broadcasts, c.broadcast_messages, c.broadcast_bytes} == {1, 0, 0}
  end
end
