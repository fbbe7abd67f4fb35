defmodule Tartarus.EventsTest do
  use Tartarus.HostCase, async: false

  alias Tartarus.Events

  doctest Events

  setup do
    :ok = Events.subscribe()
  end

  # The next event of `type` about agent `id`.
  defmacrop assert_event(type, id) do
    quote do
      assert_receive {:tartarus_event, %{type: unquote(type), agent: ^unquote(id)} = event}, 1_000
      assert is_integer(event.time)
      event
    end
  end

  test "counter_names/0 lists the documented counters; totals/0 has them all" do
    documented =
      [:created, :arrivals, :departures, :move_failed, :clones, :kills, :stopped, :crashes] ++
        [:removed, :messages, :message_bytes, :bytes, :code_bytes, :refused]

    assert documented -- Events.counter_names() == []
    assert Map.keys(Events.totals()) |> Enum.sort() == Enum.sort(Events.counter_names())
    assert Enum.all?(Events.totals(), fn {_, n} -> is_integer(n) and n >= 0 end)
  end

  test "created, departure and arrival events carry the documented keys" do
    [a, b] = line!(2)
    before = Events.totals()
    id = agent!(a)

    created = assert_event(:created, id)
    assert Map.keys(created) |> Enum.sort() == [:agent, :host, :module, :time, :type]
    assert created.host == addr(a)
    assert created.module == Probe

    :ok = Tartarus.move({id, a}, b)
    departure = assert_event(:departure, id)

    assert Map.keys(departure) |> Enum.sort() == [
             :agent,
             :bytes,
             :code_bytes,
             :host,
             :time,
             :to,
             :type
           ]

    assert departure.host == addr(a)
    assert departure.to == addr(b)
    assert departure.bytes > 0
    assert departure.code_bytes >= 0

    arrival = assert_event(:arrival, id)

    assert Map.keys(arrival) |> Enum.sort() == [
             :agent,
             :from,
             :hop_us,
             :hops,
             :host,
             :time,
             :type
           ]

    assert arrival.host == addr(b)
    assert arrival.from == addr(a)
    assert arrival.hops == 1
    assert arrival.hop_us >= 0

    now = Events.totals()
    assert now.created >= before.created + 1
    assert now.departures >= before.departures + 1
    assert now.arrivals >= before.arrivals + 1
    assert now.bytes >= before.bytes + departure.bytes
  end

  test "move_failed, clone, message, kill events" do
    [a, b] = line!(2)
    x = unique_name()
    id = agent!(a)

    {:error, _} = Tartarus.move({id, a}, x)
    failed = assert_event(:move_failed, id)
    assert failed.to == x
    assert failed.reason == {:unknown_host, addr(x)}
    assert failed.host == addr(a)

    {:ok, clone} = Tartarus.clone({id, a}, b)
    event = assert_event(:clone, id)
    assert %{clone: ^clone, host: {^a, _}, to: {^b, _}} = event

    :ok = Tartarus.post({id, a}, :inc)
    message = assert_event(:message, id)
    assert message.bytes == :erlang.external_size(:inc)

    :ok = Tartarus.kill({id, a})
    assert %{host: {^a, _}} = assert_event(:kill, id)

    counts = Tartarus.status(a).counts
    assert counts.move_failed == 1
    assert counts.clones == 1
    assert counts.messages == 1
    assert counts.message_bytes == :erlang.external_size(:inc)
    assert counts.kills == 1
  end

  test "stopped, crash, removed, refused events" do
    [a, b] = line!(2)
    h = host!(max_restarts: 0)
    id = agent!(a, %{}, ttl: 1)

    :ok = Tartarus.move({id, a}, b)
    {:error, {:ttl_expired, 1}} = Tartarus.move({id, a}, a)
    refused = assert_event(:refused, id)
    assert %{host: {^a, _}, from: {^b, _}, reason: {:ttl_expired, 1}} = refused

    :ok = Tartarus.post({id, a}, {:do, {:stop, :enough}})
    assert %{reason: :enough, host: {^b, _}} = assert_event(:stopped, id)

    doomed = agent!(h)
    :ok = Tartarus.post({doomed, h}, :crash)
    crash = assert_event(:crash, doomed)
    assert crash.restarts == 0
    assert {:error, %RuntimeError{}, _} = crash.reason
    removed = assert_event(:removed, doomed)
    assert {:too_many_restarts, _} = removed.reason
  end

  test "a budgeted subscriber gets the first events of its window only; type_totals/0 counts them all" do
    [a, b] = line!(2)
    id = agent!(a)
    # A window of an hour: the test lies in one (or, once an hour, two) of them.
    watcher = counting_subscriber({5, 3_600_000})
    types0 = Events.type_totals()
    totals0 = Events.totals()

    Enum.reduce(1..20, a, fn _, at ->
      to = if at == a, do: b, else: a
      :ok = Tartarus.move({id, at}, to)
      to
    end)

    types = Events.type_totals()
    assert types.arrival - types0.arrival == Events.totals().arrivals - totals0.arrivals
    assert types.arrival - types0.arrival >= 20
    assert types.departure - types0.departure >= 20

    # This (unbudgeted) test process got every one of them.
    for _ <- 1..20, do: assert_event(:arrival, id)

    send(watcher, {:count, self()})
    assert_receive {:count, n}
    assert n >= 5 and n <= 10

    # Short windows: the budget comes back in each new window.
    short = counting_subscriber({3, 100})

    Enum.reduce(1..6, a, fn _, at ->
      Process.sleep(120)
      to = if at == a, do: b, else: a
      :ok = Tartarus.move({id, at}, to)
      to
    end)

    send(short, {:count, self()})
    assert_receive {:count, got}
    # Six windows of two events or more each (a departure and an arrival): 3 from each at most.
    assert got >= 12 and got <= 18
    assert_raise ArgumentError, fn -> Events.subscribe(budget: {0, 10}) end
  end

  # A process subscribed with `budget` that counts the events it gets and tells `{:count, n}`
  # to whoever sends it `{:count, pid}`.
  defp counting_subscriber(budget) do
    me = self()

    pid =
      spawn_link(fn ->
        :ok = Events.subscribe(budget: budget)
        send(me, :subscribed)
        count_events(0)
      end)

    assert_receive :subscribed
    pid
  end

  defp count_events(n) do
    receive do
      {:tartarus_event, _} -> count_events(n + 1)
      {:count, from} -> send(from, {:count, n})
    end
  end

  test "unsubscribe/0 ends the subscription" do
    :ok = Events.unsubscribe()
    h = host!()
    id = agent!(h)
    refute_receive {:tartarus_event, %{agent: ^id}}, 50
  end
end
