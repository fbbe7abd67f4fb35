defmodule TartarusLats.DatabaseAgent do
  @moduledoc """
  The static Database agent of a LATS node (thesis §3.3.3): one per host,
  named `"lats-db"` on every host so that neighbours address it as
  `{"lats-db", host}`.

  It reads its node's BLE receiver through the plugin channel
  (`TartarusLats.BeaconPlugin`, attached as `:beacon`), runs the pure
  `TartarusLats.Tracker` and `TartarusLats.MotionVectors`, keeps the node's
  log of records and its motion-vector table, and exchanges the handshake
  messages with the database agents of the neighbouring hosts
  (`Tartarus.post/3`).

  ## What it publishes in the host store

  Query agents read these locally with `Tartarus.Agent.store_get/2`:

    * `{:lats, :node}` - this node's (zone's) name;
    * `{:lats, :entrance}` - whether people can come in from outside in this node's
      zone (a door to the outside; default `true`: a deployment that does not say);
    * `{:lats, :neighbours}` - `%{neighbour_node => host}`;
    * `{:lats, :mv}` - the `TartarusLats.MotionVectors` table;
    * `{:lats, :log}` - the log of records (`t:TartarusLats.Tracker.record/0`),
      newest first;
    * `{:lats, :clock}` - the last world second processed;
    * `{:lats, :cloud}` - the cloud host, or `nil`;
    * `{:lats, :filtered}` - `%{tag => filtered RSSI}` of the last second;
    * `{:lats, :held}` - the tags the zone decision holds in this node's zone now.

  ## Driven in world seconds

  The agent does nothing by itself: the scenario driver (see
  `TartarusLats.Deployment`) advances the world one second at a time and
  then asks every database agent, in phases, with `Tartarus.request/3`:

    1. `{:sense, t}` - scan the receiver, run the tracker, log records, and
       post this node's zone report (`TartarusLats.Zone.report/2`: its RSSI of
       every tag it hears or holds, and which it holds) to the neighbours;
    2. `{:deliver, t, j}` for `j = 1, 2, ...` while messages flow (the first
       always) - in the first, decide the zone on the neighbours' reports
       (`TartarusLats.Zone.decide/4`) and feed the `:entered_zone` /
       `:left_zone` decisions to the motion vectors; in every one, apply the
       handshake messages sent in earlier phases, in a fixed order (sorted),
       and post the answers;
    3. `{:tick, t}` - the one-holder protocol's claims of the second arbitrated
       (`TartarusLats.Zone.close/2`, with the zone option `:one_holder`), handshake
       timeouts (counted in world seconds, never wall time) and publishing.

  With `:one_holder`, the zone protocol's messages (asks, gives, flooded ledger entries
  and claim intents: `TartarusLats.Zone.take_out/1`) travel with the handshake messages to
  the neighbours' database agents and are applied (`TartarusLats.Zone.deliver/3`) before
  them in every delivery.

  The agent posts its handshake messages (and its upload) with
  `Tartarus.cast/3`, so two database agents never wait for each other, and
  answers the phase with what it sent: `{:ok, %{sent: %{host => n},
  uploads: 0 | 1}}`. The driver then closes the phase with a barrier: it
  asks every receiver `{:sync, n}` (answered once the agent has taken `n`
  handshake messages in all since it started) and the cloud the same
  (`TartarusLats.Cloud`), so when the barrier is passed, every message of
  the phase is where it belongs: runs are deterministic for a seed however
  the hosts are scheduled. Every message carries the phase it was sent in
  (`{t, 0}` for the sense phase, `{t, j}` for delivery `j`) and is applied
  at the first delivery of a later phase: a fast neighbour's message of
  delivery `j` that arrives before this agent's own delivery `j` waits for
  delivery `j + 1`, as it would if the neighbour had been slow.

  ## Durable log

  With `data_dir` set, the log and the motion-vector table are written to a
  DETS file `<data_dir>/<node>.dets` (synced after every change) and
  reloaded when the agent starts again, e.g. after a host restart. The
  tracker's filter state is not kept (after a restart every tag starts
  "beyond"). The platform has no generic persistence of host stores yet, so
  this lives inside LATS.

  ## The cloud (centralized design, thesis Scenario 1)

  With `centralized: true` the agent uploads, in one post to the cloud agent
  (`TartarusLats.Cloud`) at the end of every second that produced anything
  (the tick phase), the second's new records and its new or changed stays
  (only those: a stay is known by its arrival time): one connection per
  upload, so at most one per node per second.

  ## Arguments of `init/1`

  A map with `:node` (required), `:neighbours` (`%{node => host}`),
  `:cloud` (host or nil), `:centralized` (boolean), `:data_dir` (path or
  nil), `:tracker` (options of `TartarusLats.Tracker.new/1`), `:zone`
  (options of `TartarusLats.Zone.new/1`; the tracker's calibration is passed on; or
  `:tracker`: no zone decision, the thesis's own rule: the tracker's own
  `:entered_zone` / `:left_zone` events, far or near against beyond on its moving average,
  drive the motion vectors, and every tag the tracker hears far or near counts as held),
  `:timeout`
  (handshake timeout in seconds, default 15).
  """
  use Tartarus.Agent

  alias Tartarus.Agent, as: A
  alias TartarusLats.{MotionVectors, Tracker, Zone}

  @name "lats-db"

  @doc "The name of the database agent on every host."
  @spec agent_name() :: String.t()
  def agent_name, do: @name

  @impl true
  def init(args) when is_map(args) do
    node = Map.fetch!(args, :node)
    # `zone: :tracker`: the thesis's own rule, no zone decision (see the moduledoc).
    {rule, zone_opts} =
      case Map.get(args, :zone, []) do
        :tracker -> {:tracker, []}
        opts -> {:zone, opts}
      end

    s = %{
      rule: rule,
      node: node,
      neighbours: Map.get(args, :neighbours, %{}),
      cloud: Map.get(args, :cloud),
      centralized: Map.get(args, :centralized, false),
      tracker: Tracker.new(Map.get(args, :tracker, [])),
      zone:
        Zone.new(
          Keyword.take(Map.get(args, :tracker, []), [:calibration]) ++
            zone_opts ++
            [node: node, neighbours: Map.keys(Map.get(args, :neighbours, %{}))]
        ),
      mv: MotionVectors.new(node, timeout: Map.get(args, :timeout, 15)),
      log: [],
      seq: 0,
      clock: 0,
      inbox: [],
      received: 0,
      waiting: [],
      unsent: {[], %{}},
      dets: nil
    }

    s = open_log(s, Map.get(args, :data_dir))
    A.store_put({:lats, :node}, node)
    A.store_put({:lats, :entrance}, Map.get(args, :entrance, true))
    A.store_put({:lats, :neighbours}, s.neighbours)
    A.store_put({:lats, :cloud}, s.cloud)
    A.store_put({:lats, :filtered}, %{})
    A.store_put({:lats, :held}, [])
    publish(s)
    {:stay, s}
  end

  @impl true
  def handle_message({:mv, stamp, msg}, _from, s),
    do: {:stay, release(%{s | inbox: [{stamp, msg} | s.inbox], received: s.received + 1})}

  def handle_message({:sync, n}, from, s),
    do: {:stay, release(%{s | waiting: [{n, from} | s.waiting]})}

  def handle_message({:sense, t}, from, s) do
    # Whatever receiver is attached: only well-formed readings reach the tracker.
    readings =
      case A.read(:beacon, {:scan, t}) do
        {:ok, readings} when is_map(readings) ->
          Map.filter(readings, &TartarusLats.BeaconPlugin.valid_reading?/1)

        _ ->
          %{}
      end

    {events, tracker} = Tracker.tick(s.tracker, t, readings)

    A.store_put(
      {:lats, :filtered},
      Map.new(Tracker.tags(tracker), &{&1, Tracker.average(tracker, &1)})
    )

    # The zone is decided in the first delivery, on every neighbour's report of this second
    # (TartarusLats.Zone): the tracker's own zone events are not used.
    records = for {:record, r} <- events, do: r
    s = %{s | tracker: tracker, clock: t} |> append_log(records)
    sense(s, t, events, records, from)
  end

  def handle_message({:deliver, t, j}, from, %{rule: :tracker} = s) do
    {ready, later} = Enum.split_with(s.inbox, fn {stamp, _} -> stamp < {t, j} end)

    {s, out, changed} =
      apply_events(%{s | inbox: later}, t, Enum.sort(Enum.map(ready, &elem(&1, 1))))

    {:stay, send_all(pending(s, [], changed), from, {t, j}, out)}
  end

  def handle_message({:deliver, t, j}, from, s) do
    {ready, later} = Enum.split_with(s.inbox, fn {stamp, _} -> stamp < {t, j} end)

    {reports, inbox} =
      ready |> Enum.map(&elem(&1, 1)) |> Enum.split_with(&match?({:rss, _, _}, &1))

    {protocol, inbox} = Enum.split_with(inbox, &zone_msg?/1)
    s = %{s | inbox: later}

    # The first delivery of a second decides the zone on the reports of that second; every
    # delivery applies the one-holder protocol's messages (TartarusLats.Zone.deliver/3).
    {decided, s} =
      if j == 1 do
        heard = Map.new(reports, fn {:rss, node, report} -> {node, report} end)
        {events, zone} = Zone.decide(s.zone, t, s.tracker, heard)
        {events, %{s | zone: zone}}
      else
        {[], s}
      end

    {delivered, zone} =
      if protocol == [], do: {[], s.zone}, else: Zone.deliver(s.zone, t, protocol)

    {zone_out, zone} = Zone.take_out(zone)
    if j == 1 or protocol != [], do: A.store_put({:lats, :held}, Zone.held(zone))
    s = %{s | zone: zone}

    {s, out, changed} = apply_events(s, t, decided ++ delivered ++ Enum.sort(inbox))
    {:stay, send_all(pending(s, [], changed), from, {t, j}, zone_msgs(s, zone_out) ++ out)}
  end

  def handle_message({:tick, t}, from, s) do
    # The one-holder protocol's claims of this second are arbitrated once all its messages
    # are in (TartarusLats.Zone.close/2).
    {claimed, zone} = Zone.close(s.zone, t)
    if claimed != [], do: A.store_put({:lats, :held}, Zone.held(zone))
    {s, out, changed} = apply_events(%{s | clock: t, zone: zone}, t, claimed ++ [:tick])
    A.store_put({:lats, :clock}, t)
    {:stay, send_all(pending(s, [], changed), from, {t, :tick}, out)}
  end

  def handle_message(:state, from, s) do
    A.reply(from, %{node: s.node, mv: s.mv, log: s.log, clock: s.clock})
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  # The sense phase's end: with the zone decision, this node's report to its neighbours;
  # with the thesis's own rule (`zone: :tracker`), the tracker's own zone events go to the
  # motion vectors and the tags it hears far or near are held.
  defp sense(%{rule: :tracker} = s, t, events, records, from) do
    zone_events = for {kind, _, _} = e <- events, kind in [:entered_zone, :left_zone], do: e

    A.store_put(
      {:lats, :held},
      Enum.sort(
        for tag <- Tracker.tags(s.tracker), Tracker.region(s.tracker, tag) != :beyond, do: tag
      )
    )

    {s, out, changed} = apply_events(s, t, zone_events)
    {:stay, send_all(pending(s, records, changed), from, {t, 0}, out)}
  end

  defp sense(s, t, _events, records, from) do
    report = Zone.report(s.zone, s.tracker)

    out =
      if report == %{},
        do: [],
        else: for({_n, host} <- Enum.sort(s.neighbours), do: {host, {:rss, s.node, report}})

    {:stay, send_all(pending(s, records, []), from, {t, 0}, out)}
  end

  defp zone_msg?(msg), do: is_tuple(msg) and tuple_size(msg) > 1 and elem(msg, 0) == :zone

  # The one-holder protocol's messages, to the neighbours' hosts.
  defp zone_msgs(s, msgs),
    do: for({node, msg} <- msgs, h = s.neighbours[node], do: {h, msg})

  # Answers the `{:sync, n}` requests whose count has been reached.
  defp release(s) do
    {done, waiting} = Enum.split_with(s.waiting, fn {n, _} -> s.received >= n end)
    Enum.each(done, fn {_, from} -> A.reply(from, :ok) end)
    %{s | waiting: waiting}
  end

  # -- events -----------------------------------------------------------------

  defp apply_events(s, _t, []), do: {s, [], []}

  defp apply_events(s, t, events) do
    before = s.mv.tags

    {mv, actions} =
      Enum.reduce(events, {s.mv, []}, fn event, {mv, acc} ->
        {mv, actions} = MotionVectors.handle(mv, t, event)
        {mv, acc ++ actions}
      end)

    out =
      Enum.flat_map(actions, fn
        {:broadcast, msg} -> for {_n, host} <- Enum.sort(s.neighbours), do: {host, msg}
        {:send, node, msg} -> if h = s.neighbours[node], do: [{h, msg}], else: []
      end)

    # Only what is new: per tag, the stays added or changed since the last upload (a stay is
    # known by its arrival time; the cloud merges them into its mirror).
    changed =
      for {tag, segs} <- mv.tags,
          old = Map.get(before, tag, []),
          old != segs,
          do: {tag, segs -- old}

    s = %{s | mv: mv}

    if changed != [] do
      persist(s, :mv, mv)
      A.store_put({:lats, :mv}, mv)
    end

    {s, out, changed}
  end

  # What the cloud has not been sent yet: this second's records, and per tag the new or
  # changed stays by arrival time (a stay changed twice in a second goes once, as it is last).
  defp pending(s, records, changed) do
    {recs, vecs} = s.unsent

    vecs =
      Enum.reduce(changed, vecs, fn {tag, segs}, vecs ->
        Map.update(vecs, tag, Map.new(segs, &{&1.arrived_at, &1}), fn by_arrival ->
          Enum.reduce(segs, by_arrival, &Map.put(&2, &1.arrived_at, &1))
        end)
      end)

    %{s | unsent: {Enum.reverse(records, recs), vecs}}
  end

  # Casts the handshake messages and, in the tick phase, the second's upload (one
  # connection per node per second with news), and tells the driver what went where (the
  # driver's barrier waits for them, see the moduledoc).
  defp send_all(s, from, {t, phase} = stamp, out) do
    Enum.each(out, fn {host, msg} -> :ok = Tartarus.cast({@name, host}, {:mv, stamp, msg}) end)
    {upload, s} = if phase == :tick, do: upload(s, t), else: {nil, s}
    if upload, do: :ok = Tartarus.cast({TartarusLats.Cloud.agent_name(), s.cloud}, upload)
    sent = Enum.frequencies_by(out, fn {host, _} -> host end)
    A.reply(from, {:ok, %{sent: sent, uploads: if(upload, do: 1, else: 0)}})
    s
  end

  defp upload(%{centralized: true, cloud: cloud, unsent: {recs, vecs}} = s, t)
       when cloud != nil and (recs != [] or vecs != %{}) do
    vectors =
      for {tag, by_arrival} <- Enum.sort(vecs),
          do: {tag, by_arrival |> Map.values() |> Enum.sort_by(& &1.arrived_at, :desc)}

    msg = {:upload, %{node: s.node, time: t, records: Enum.reverse(recs), vectors: vectors}}
    {msg, %{s | unsent: {[], %{}}}}
  end

  defp upload(s, _t), do: {nil, %{s | unsent: {[], %{}}}}

  # -- log and persistence ------------------------------------------------------

  defp append_log(s, []), do: s

  defp append_log(s, records) do
    {log, seq} =
      Enum.reduce(records, {s.log, s.seq}, fn r, {log, seq} ->
        persist(s, {:record, seq + 1}, r)
        {[r | log], seq + 1}
      end)

    A.store_put({:lats, :log}, log)
    %{s | log: log, seq: seq}
  end

  defp open_log(s, nil), do: s

  defp open_log(s, dir) do
    File.mkdir_p!(dir)
    file = Path.join(dir, "#{s.node}.dets") |> String.to_charlist()
    name = {__MODULE__, A.host()}
    {:ok, ^name} = :dets.open_file(name, file: file, type: :set)

    records =
      :dets.select(name, [{{{:record, :"$1"}, :"$2"}, [], [{{:"$1", :"$2"}}]}])
      |> Enum.sort()

    mv =
      case :dets.lookup(name, :mv) do
        [{:mv, %MotionVectors{} = mv}] -> mv
        _ -> s.mv
      end

    log = records |> Enum.map(&elem(&1, 1)) |> Enum.reverse()
    seq = if records == [], do: 0, else: records |> List.last() |> elem(0)
    A.store_put({:lats, :log}, log)
    %{s | dets: name, log: log, seq: seq, mv: mv}
  end

  defp persist(%{dets: nil}, _key, _value), do: :ok

  defp persist(%{dets: name}, key, value) do
    :ok = :dets.insert(name, {key, value})
    :dets.sync(name)
  end

  defp publish(s) do
    A.store_put({:lats, :mv}, s.mv)
    A.store_put({:lats, :log}, s.log)
    A.store_put({:lats, :clock}, s.clock)
  end
end
