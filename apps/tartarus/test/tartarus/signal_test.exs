defmodule Tartarus.SignalTest do
  # Signal fields on small graphs of virtual hosts: decay with distance, span cut-off,
  # evaporation, strongest contribution per source, message counts, and an agent climbing
  # the field with {:gradient, name}.
  use Tartarus.HostCase, async: false

  alias Tartarus.Signal

  doctest Signal

  defmodule Climber do
    @moduledoc false
    # Climbs signal `name` until no neighbour is stronger than its host; returns where it
    # stopped, its hops and the path.
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(name), do: step(%{name: name, path: [A.host()]})

    @impl true
    def handle_arrival(ctx, s), do: step(%{s | path: s.path ++ [ctx.host]})

    defp step(s) do
      here = A.signal(s.name)
      best = s.name |> A.gradient() |> Map.values() |> Enum.max(fn -> 0.0 end)

      if here > 0 and here >= best,
        do: {:return, {A.host(), A.hops(), s.path}, s},
        else: {:move, {:gradient, s.name}, s}
    end
  end

  defp values(hosts, name), do: Enum.map(hosts, &Float.round(Tartarus.signal(&1, name), 3))

  defp counts(host), do: Tartarus.status(host).counts

  # A w x w grid, row by row.
  defp grid!(w) do
    hosts = hosts!(w * w)
    at = fn r, c -> Enum.at(hosts, r * w + c) end

    for r <- 0..(w - 1), c <- 0..(w - 1) do
      if c + 1 < w, do: :ok = Tartarus.connect(at.(r, c), at.(r, c + 1))
      if r + 1 < w, do: :ok = Tartarus.connect(at.(r, c), at.(r + 1, c))
    end

    hosts
  end

  test "the strength decays with distance: the thesis's linear law by default" do
    hosts = line!(5)
    :ok = Tartarus.emit_signal(hd(hosts), :danger, 100, span: 4)
    :ok = Signal.settle()
    assert values(hosts, :danger) == [100.0, 75.0, 50.0, 25.0, 0.0]

    hosts = line!(4)
    :ok = Tartarus.emit_signal(hd(hosts), :heat, 80, span: 3, decay: {:exponential, 0.5})
    :ok = Signal.settle()
    assert values(hosts, :heat) == [80.0, 40.0, 20.0, 10.0]
  end

  test "the span cuts the field off, whatever the decay" do
    hosts = line!(6)
    [a, b, c, d, _, _] = hosts
    :ok = Tartarus.emit_signal(a, :s, 100, span: 2, decay: :none)
    :ok = Signal.settle()
    assert values(hosts, :s) == [100.0, 100.0, 100.0, 0.0, 0.0, 0.0]
    # Relays: a -> b, b -> c; c is at the span and relays no more.
    assert counts(a).signal_messages == 1
    assert counts(b).signal_messages == 1
    assert counts(c).signal_messages == 0
    assert counts(d).signal_messages == 0
    assert counts(a).signals == 1
    assert counts(a).signal_bytes > 0
    # One message each: the same size but for the host names and the age it carries.
    assert abs(counts(b).signal_bytes - counts(a).signal_bytes) < 16
    # d knows nothing; c knows b's value (b relayed to it), b knows a's.
    assert Signal.neighbour_values(d, :s) == %{}
    assert Signal.neighbour_values(c, :s) == %{addr(b) => 100.0}
    assert Signal.neighbour_values(b, :s) == %{addr(a) => 100.0}
  end

  test "a host keeps the strongest contribution per source (ring: the shorter way wins)" do
    hosts = ring!(6)
    :ok = Tartarus.emit_signal(hd(hosts), :p, 80, span: 5, decay: {:exponential, 0.5})
    :ok = Signal.settle()
    assert values(hosts, :p) == [80.0, 40.0, 20.0, 10.0, 20.0, 40.0]
    [c] = Signal.contributions(Enum.at(hosts, 2), :p)
    assert c.hops == 2 and c.source == addr(hd(hosts))
  end

  defmodule EveryLink5ms do
    @moduledoc false
    @behaviour Tartarus.Transport
    @impl true
    def hand_off(_host, _dest, rng), do: {:ok, rng}
    @impl true
    def message_delay(_from, _to), do: 5
  end

  # Each host has its own overlay process, as on a network of devices: copies reach a host
  # in the order of their paths' costs only when links cost time. So the ring runs in
  # virtual time with 5 ms links (a copy that came the long way arrives later).
  test "one emission is relayed at most once per host, even around a cycle" do
    Tartarus.Transport.install(EveryLink5ms)
    on_exit(&Tartarus.Transport.clear/0)

    Tartarus.Clock.Virtual.run([seed: 1], fn ->
      hosts = ring!(6)
      :ok = Tartarus.emit_signal(hd(hosts), :flat, 10, span: 5, decay: :none, lifetime: 600_000)
      :ok = Signal.settle()
      assert Enum.all?(values(hosts, :flat), &(&1 > 9.0 and &1 <= 10.0))
      sent = Enum.map(hosts, &counts(&1).signal_messages)
      # The emitter sends to its two neighbours; every other host relays at most once, to
      # its one other neighbour; the host opposite takes the first copy only.
      assert hd(sent) == 2
      assert Enum.all?(tl(sent), &(&1 <= 1))
      assert Enum.sum(sent) <= 7
    end)
  end

  test "contributions of several sources combine by max (default) or sum, and carry data" do
    [a, b, c] = line!(3)
    :ok = Tartarus.emit_signal(a, :d, 10, span: 2, decay: :none, data: [0.1, 0.2])
    :ok = Tartarus.emit_signal(c, :d, 30, span: 2, decay: :none, data: [0.9])
    :ok = Signal.settle()
    assert Tartarus.signal(b, :d) == 30.0
    assert Tartarus.signal(b, :d, combine: :sum) == 40.0

    assert [%{source: src1, value: 30.0, data: [0.9]}, %{value: 10.0, data: [0.1, 0.2]}] =
             Signal.contributions(b, :d)

    assert src1 == addr(c)
  end

  test "settle/1 says when it timed out: a host's overlay did not get through its messages in time" do
    [a, b] = line!(2)
    overlay = Tartarus.Host.overlay_pid(b)
    me = self()

    # The host's overlay held in a system message until released (as if busy with a long
    # relay), with a broadcast waiting behind; released whatever happens to the test.
    on_exit(fn -> send(overlay, :release) end)

    holder =
      Task.async(fn ->
        :sys.replace_state(
          overlay,
          fn state ->
            send(me, :overlay_held)

            receive do
              :release -> state
            end
          end,
          :infinity
        )
      end)

    assert_receive :overlay_held
    send(overlay, {:"$tartarus_broadcast", addr(b), addr(a), :hello})
    assert Signal.settle(50) == {:error, :timeout}
    send(overlay, :release)
    Task.await(holder)
    assert Signal.settle() == :ok
  end

  test "the signal evaporates with time, computed on read" do
    hosts = line!(3)
    [a, b, c] = hosts
    # Long-lived: after the field settles it is worth at most its base, and more than 0.
    :ok = Tartarus.emit_signal(a, :long, 100, span: 3, lifetime: 600_000)
    :ok = Signal.settle()
    [va, vb, vc] = values(hosts, :long)
    assert va <= 100.0 and va > 99.0
    assert vb <= 66.667 and vb > 65.0
    assert vc <= 33.334 and vc > 32.0

    # Short-lived: gone everywhere once its lifetime has passed, with nothing running.
    :ok = Tartarus.emit_signal(a, :short, 100, span: 3, lifetime: 30, evaporation: :step)
    :ok = Signal.settle()
    Process.sleep(60)
    assert values(hosts, :short) == [0.0, 0.0, 0.0]
    assert Signal.contributions(b, :short) == []
    assert Signal.neighbour_values(c, :short) == %{}
  end

  test "the lifetime may decay with hops too (thesis Eq. 6.5)" do
    {:ok, e} = Signal.emission(100, span: 2, lifetime: 1_000, lifetime_decay: :linear)
    near = Signal.contribution(e, {:a, :n}, 0, 0)
    far = Signal.contribution(e, {:a, :n}, 1, 0)
    assert {near.life, far.life} == {1_000_000, 500_000}
    # At 600 ms the one-hop contribution is gone, the source's is not.
    assert Signal.worth(far, 600_000) == 0.0
    assert Signal.worth(near, 600_000) == 40.0
  end

  test "a stronger re-emission replaces a weaker contribution; a weaker one does not" do
    [a, b] = line!(2)
    :ok = Tartarus.emit_signal(a, :x, 10, span: 1, decay: :none)
    :ok = Signal.settle()
    :ok = Tartarus.emit_signal(a, :x, 50, span: 1, decay: :none)
    :ok = Signal.settle()
    assert Tartarus.signal(b, :x) == 50.0
    :ok = Tartarus.emit_signal(a, :x, 20, span: 1, decay: :none)
    :ok = Signal.settle()
    assert Tartarus.signal(b, :x) == 50.0
    # The weaker emission was not relayed: two relays in all.
    assert counts(a).signal_messages == 2
    assert counts(a).signals == 3
  end

  test "an agent following {:gradient, name} reaches the emitter on a line and on a grid" do
    hosts = line!(5)
    :ok = Tartarus.emit_signal(List.last(hosts), :danger, 100, span: 4)
    :ok = Signal.settle()
    {:ok, id} = Tartarus.create_mobile_agent(hd(hosts), Climber, :danger, owner: self())
    assert_receive {:tartarus_result, ^id, {top, 4, path}}, 5_000
    assert top == addr(List.last(hosts))
    assert path == Enum.map(hosts, &addr/1)

    # 3x3 grid, source in a corner, climber in the opposite one: a shortest path (4 hops).
    g = grid!(3)
    :ok = Tartarus.emit_signal(Enum.at(g, 8), :pher, 100, span: 4, decay: {:exponential, 0.7})
    :ok = Signal.settle()
    {:ok, id} = Tartarus.create_mobile_agent(hd(g), Climber, :pher, owner: self())
    assert_receive {:tartarus_result, ^id, {top, 4, _path}}, 5_000
    assert top == addr(Enum.at(g, 8))
  end

  defmodule Waiter do
    @moduledoc false
    # Waits on its host for signal `name` without polling (a watch), then climbs it.
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(name) do
      :ok = A.watch_signal(name)
      send(self(), {:tartarus_signal, A.host(), name})
      {:stay, %{name: name, woken: 0}}
    end

    @impl true
    def handle_info({:tartarus_signal, _host, name}, %{name: name} = s) do
      s = %{s | woken: s.woken + 1}
      if A.signal(name) > 0, do: climb(s), else: {:stay, s}
    end

    @impl true
    def handle_arrival(_ctx, s), do: climb(s)

    defp climb(s) do
      best = s.name |> A.gradient() |> Map.values() |> Enum.max(fn -> 0.0 end)

      if A.signal(s.name) >= best,
        do: {:return, {A.host(), s.woken}, s},
        else: {:move, {:gradient, s.name}, s}
    end
  end

  test "an agent watching a signal is woken when the field reaches its host, and its watch ends when it leaves" do
    [a, _b, c] = hosts = line!(3)
    {:ok, id} = Tartarus.create_mobile_agent(c, Waiter, :food, owner: self())
    # Nothing to wake it: it stays, watching (its own first look found no field).
    assert eventually(fn -> Signal.watchers(c, :food) != [] end, 5_000)
    refute_receive {:tartarus_result, ^id, _}, 100

    :ok = Tartarus.emit_signal(a, :food, 100, span: 3)
    assert_receive {:tartarus_result, ^id, {top, woken}}, 5_000
    assert top == addr(a)
    # Woken once by its own first look and once by the field (one emission, one change).
    assert woken == 2
    # It left c: its watch went with it.
    assert eventually(fn -> Signal.watchers(c, :food) == [] end, 5_000)
    assert Enum.all?(hosts, &(Signal.watchers(&1, :food) == []))
  end

  test "watch and unwatch from any process; a watcher that exits is forgotten" do
    [a, b] = line!(2)
    :ok = Signal.watch(b, :w)
    :ok = Signal.watch(b, :w)
    assert Signal.watchers(b, :w) == [self()]
    :ok = Tartarus.emit_signal(a, :w, 10, span: 2)
    bref = addr(b)
    assert_receive {:tartarus_signal, ^bref, :w}, 5_000
    refute_receive {:tartarus_signal, _, :w}, 50
    # Another name at the same host wakes nobody.
    :ok = Tartarus.emit_signal(a, :other, 10, span: 2)
    :ok = Signal.settle()
    refute_receive {:tartarus_signal, _, _}, 50

    :ok = Signal.unwatch(b, :w)
    assert Signal.watchers(b, :w) == []
    :ok = Tartarus.emit_signal(a, :w, 20, span: 2)
    :ok = Signal.settle()
    refute_receive {:tartarus_signal, _, :w}, 50

    pid = spawn(fn -> receive do: (:stop -> :ok) end)
    :ok = Signal.watch(b, :w, pid)
    assert Signal.watchers(b, :w) == [pid]
    send(pid, :stop)
    assert eventually(fn -> Signal.watchers(b, :w) == [] end, 5_000)
    assert {:error, {:unknown_host, _}} = Signal.watch({:nowhere, node()}, :w)
  end

  test "hosts named like the overlay's own tags or like match syntax break nothing" do
    overlay = Process.whereis(:tartarus_overlay)
    {:ok, _} = Tartarus.start_host(:watch)
    {:ok, _} = Tartarus.start_host(:_, neighbours: [:watch])
    [other] = line!(1)
    :ok = Tartarus.emit_signal(other, :kept, 10, span: 1)
    :ok = Tartarus.emit_signal(:watch, :f, 10, span: 2)
    :ok = Signal.settle()

    # A broadcast subscriber of the host named :watch exits: the overlay forgets it and lives.
    pid = spawn(fn -> receive do: (:stop -> :ok) end)
    :ok = Tartarus.Broadcast.subscribe(:watch, pid)
    send(pid, :stop)
    assert eventually(fn -> Tartarus.Broadcast.subscribers(:watch) == [] end, 5_000)
    assert Process.whereis(:tartarus_overlay) == overlay

    # The host named :_ stops: only its own fields go.
    assert Tartarus.signal(:_, :f) > 0
    :ok = Tartarus.stop_host(:_)
    assert eventually(fn -> :ets.lookup(:tartarus_signals, {:_, :f}) == [] end, 5_000)
    assert Tartarus.signal(other, :kept) == 10.0
    assert Tartarus.signal(:watch, :f) == 10.0
    :ok = Tartarus.stop_host(:watch)
  end

  test "{:gradient, name} breaks ties at random, reproducibly for a stream" do
    ns = [{:b, :n}, {:c, :n}, {:d, :n}]

    info = %{
      here: {:a, :n},
      neighbours: ns,
      visits: %{},
      gradients: %{g: Map.new(ns, &{&1, 5.0})}
    }

    pick = fn seed ->
      elem(Tartarus.Strategy.choose({:gradient, :g}, info, :rand.seed_s(:exsss, seed)), 1)
    end

    picks = Enum.map(1..40, pick)
    assert length(Enum.uniq(picks)) > 1
    assert picks == Enum.map(1..40, pick)
  end

  test "agents emit and read signals from inside callbacks" do
    [a, b] = line!(2)
    id = agent!(a)

    assert inside({id, a}, :emit_signal, [:alarm, 60, [span: 1, decay: :none, data: :fire]]) ==
             :ok

    :ok = Signal.settle()
    assert Tartarus.signal(b, :alarm) == 60.0
    :ok = Tartarus.move({id, a}, b)
    assert inside({id, a}, :signal, [:alarm]) == 60.0
    assert [%{data: :fire, hops: 1}] = inside({id, a}, :signals, [:alarm])
    assert inside({id, a}, :gradient, [:alarm]) == %{addr(a) => 60.0}
    Tartarus.kill(id)
  end

  test "bad emissions are refused with a message naming the key" do
    h = host!()
    assert {:error, msg} = Tartarus.emit_signal(h, :x, 1, span: -1)
    assert msg =~ "key :span"
    assert {:error, msg} = Tartarus.emit_signal(h, :x, 1, evaporation: :sometimes)
    assert msg =~ "key :evaporation"
    assert {:error, msg} = Tartarus.emit_signal(h, :x, -3)
    assert msg =~ "strength"

    assert Tartarus.emit_signal(:no_such_host_here, :x, 1) ==
             {:error, {:unknown_host, {:no_such_host_here, node()}}}
  end

  test "a stopped host's field is dropped" do
    name = unique_name("sig")
    {:ok, _} = Tartarus.start_host(name)
    :ok = Tartarus.emit_signal(name, :gone, 5)
    assert Tartarus.signal(name, :gone) == 5.0
    :ok = Tartarus.stop_host(name)
    assert eventually(fn -> :ets.lookup(:tartarus_signals, {name, :gone}) == [] end)
  end

  test "a relay that reaches a host as it stops is taken without a crash (its table is gone)" do
    [a, b] = line!(2)
    {:ok, stale} = Tartarus.Host.local(b)
    :ok = Tartarus.stop_host(b)
    # What the overlay does with a signal for `b` it looked up just before `b` stopped.
    source = {{a, node()}, System.unique_integer()}
    packed = {source, 100, 4, :infinity, {:linear, 20.0}, :none, :linear, nil}
    me = self()

    try do
      :sys.replace_state(:tartarus_overlay, fn state ->
        send(me, {:relayed, Signal.handle_relay(stale, {a, node()}, :late, source, packed, 1, 0)})
        state
      end)
    catch
      kind, reason -> flunk("the overlay's relay raised #{inspect({kind, reason})}")
    end

    assert_receive {:relayed, :ok}
  end
end
