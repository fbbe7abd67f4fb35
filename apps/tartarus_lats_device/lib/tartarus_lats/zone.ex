defmodule TartarusLats.Zone do
  @moduledoc """
  The zone decision of thesis §3.3.1, decentralized: which zone a tag is in, decided on
  each node from its own RSSI and its neighbours', with no central server.

  A node's `TartarusLats.Tracker` says how well the node hears a tag (near, far, beyond,
  with hysteresis and debounce) and logs it. Zones overlap, though: a tag 4-5 m from two
  nodes is "far" at both, and a tag standing near a zone's edge keeps crossing the far
  threshold of the next node. So every second each node tells its neighbours, for every tag
  it hears or holds, its RSSI (`TartarusLats.Tracker.heard_average/2`: lost packets left
  out, so a short burst of them does not look like a move) and whether it holds the tag
  (`report/2`; the messages travel between the database agents, see
  `TartarusLats.DatabaseAgent`). Each node then decides for itself, by the same rule on the
  same numbers as its neighbours:

    * **evidence**: a node *hears the tag well* when it heard at least `:min_heard`
      samples in its tracker's window and their mean is at or above the far threshold
      (within about 5 m);
    * **claim** (the tag enters this zone, no neighbour holds it) when the node hears the
      tag well, `:min_heard` of those samples are themselves at or above the far
      threshold, and its RSSI is at least `:claim_db` above every neighbour's, for
      `:claim_dwell` consecutive seconds (not while a neighbour is taking the tag from a
      holder this node does not see: it waits for that hand-over). A tag that comes from
      no neighbour needs samples in range, not a mean: a 2-sample 0 dBm burst at a far
      node lifts the mean of its samples above the far threshold for a whole window, but
      claims nothing (before, it made a stay from and to INFINITY there, long enough to
      count as real, and Where is X asked there answered `:left_building`);
    * **take** (a neighbour holds it) when the node hears the tag well and its RSSI is at
      least `:margin_db` above the holder's for `:dwell` seconds, or `:fast_db` above it
      for one, and `:claim_db` above any other neighbour taking it; the holder releases it
      in the same second, by the rule below. A neighbour that is stronger still but neither
      holds nor takes the tag does not stop the hand-over: a fast walker passing through
      this zone is already nearer the next node, and the chain of zones must not skip this
      one (the next node takes the tag from here). For the same reason a take that loses its
      margin before `:dwell` seconds **completes** (dated from its first second) when the
      walker has passed on: the holder no longer hears the tag well, this node's RSSI is
      still `:claim_db` above the holder's, and a neighbour that neither holds nor takes the
      tag hears it well and at least as strongly as this node;
    * **release** (the tag leaves this zone) when some neighbour that hears the tag well has
      an RSSI at least `:margin_db` above its own for `:dwell` consecutive seconds, or
      `:fast_db` above for one (the neighbour takes the tag in the same second), or when its
      RSSI stays under the exit threshold (`:exit_db` under the far threshold: the tag is
      out of range, it left) for `:exit_dwell` seconds, or at once when a neighbour holds
      the tag too (it completed a take as above) with an RSSI at least `:claim_db` above
      its own.

  Two options make the hand-over a two-sided one, for receivers whose readings disagree
  more than the simulated radio's (chosen on real recordings, `TartarusLats.Replay`; off
  by default): with `:release_on_take` the holder lets a tag go to a neighbour only once
  that neighbour reports holding it (the rule above that lets go at once), never on its
  own reading of the margin, and with `:exit_alone` it releases a tag out of its range only
  when no neighbour hears it above the exit threshold either. Without them a hand-over
  that the holder sees and the taker does not (each node sees its own neighbours) left
  the tag with nobody for seconds while receivers still heard it.

  ## One holder per tag (`:one_holder`)

  Each node sees its neighbours only, so without more a node that is not a neighbour of
  the holder (a receiver across the room that hears the tag loudly for a while) claims it
  as if nobody held it, and the tag has two holders. With `:one_holder` (on in the
  real-data replay, `TartarusLats.Replay`) the rules above only *propose*; the protocol
  decides, and guarantees **at most one holder per tag at the end of every second**:

    * every node keeps a **ledger** per tag, `{epoch, :free | {:held, node}}`; every
      change is flooded to the whole building through the neighbours (a node passes on
      an entry newer than its own), within the second it is made (the deployment delivers
      messages in rounds until none is left), so at the start of every second all nodes
      hold the same ledger;
    * **hand-over** (a take): the taker does not take; it **asks** the holder (a
      neighbour, by definition of a take), which at the next delivery **gives** the tag to
      the strongest asker (ties: the earlier take, then the name), lets it go, and floods
      the new holder; the taker holds it from the delivery after. Both ends happen in the
      same second, dated from the take's first second. The holder never lets a tag go on
      its own reading of a neighbour's margin (as `:release_on_take`);
    * **release**: only when out of range (the exit rule: RSSI under the exit threshold
      for `:exit_dwell` seconds, with `:exit_alone` also at every neighbour): the tag went
      unheard there. The release is flooded (the tag is free). A holder that has gone (a
      neighbour the ledger says holds a tag, whose report does not say so: a live holder
      always reports what it holds) is released by its neighbours for it;
    * **claim** (a fresh one): only when the ledger says the tag is free. The claimant
      floods an **intent** (its RSSI, the claim's first second and the ledger's epoch); when
      the second's messages are all delivered, every node arbitrates the same intents on the
      same ledger (`close/2`): the strongest RSSI wins (ties: the earlier claim, then the
      name) and that node holds the tag. An intent made on an older ledger than a node's
      own is answered with the ledger entry (a node restarted with an empty ledger learns
      it so) and counts for nothing;
    * so a claim by a node that is not a neighbour of the holder is **refused by the
      ledger**, never taken: the node waits until the holder releases the tag (it went
      unheard there), then claims it afresh against any other claimant of that second.

  The holder changes only by a give to a neighbour or by a release followed, a second or
  more later, by a fresh claim. What it assumes: the messages of a second reach every
  live node within that second (a connected graph of live nodes; the deployment's
  deliveries run until no message is left, at most 100 rounds); a building split in two
  by dead nodes can have a holder in each part. `TartarusLats.Zone.Net` runs the protocol
  as a pure value (its property test: `one_holder_test.exs`).

  A neighbour that does not report a tag counts as the floor (`:missing_rssi`). The margin
  is the hysteresis: a tag standing still, even on the boundary between two zones, stays
  in the zone that holds it unless the other node is `:margin_db` stronger for `:dwell`
  seconds, which noise alone rarely gives; a tag that walks on is handed over as soon as it
  is clearly nearer the next node: the previous zone's RSS at its minimum when the next
  one's is at its maximum (§3.3.1). Two neighbours never claim one tag in the same second
  (each would have to be stronger than the other). The exit threshold is under the far
  threshold on purpose: a tag 4.5 m from its node is at the edge of "far", and its tracker
  flickers between far and beyond; the zone must not follow it.

  The decision is a plain value and pure: `decide/4` takes the second, this node's tracker
  and the neighbours' reports, and returns `:entered_zone` / `:left_zone` events (dated
  from the first second of the held condition, as the tracker dates its records) for the
  motion vectors (`TartarusLats.MotionVectors`).

      iex> z = TartarusLats.Zone.new(dwell: 1, claim_dwell: 1, min_heard: 1)
      iex> tag = {"00000000000000000000000000000001", 1, 1}
      iex> t = TartarusLats.Tracker.new(window: 1, median: 1, confirm: 1)
      iex> {_, t} = TartarusLats.Tracker.observe(t, 1, tag, -60)
      iex> {events, z} = TartarusLats.Zone.decide(z, 1, t, %{p2: %{tag => {-70.0, false}}})
      iex> events
      [{:entered_zone, tag, 1}]
      iex> TartarusLats.Zone.report(z, t)
      %{tag => {-60.0, true, true}}
      iex> {events, _z} = TartarusLats.Zone.decide(z, 2, t, %{p2: %{tag => {-53.0, false}}})
      iex> events
      [{:left_zone, tag, 2}]
  """

  alias TartarusLats.{Beacon, Tracker}

  alias TartarusLats.Region

  defstruct margin_db: 6.0,
            fast_db: 12.0,
            claim_db: 1.0,
            claim_dwell: 2,
            min_heard: 3,
            dwell: 3,
            exit_dwell: 5,
            exit_dbm: -76.0,
            exit_alone: false,
            release_on_take: false,
            far_dbm: -73.0,
            missing_rssi: -100,
            one_holder: false,
            node: nil,
            neighbours: [],
            ledger: %{},
            intents: %{},
            seen: MapSet.new(),
            out: [],
            tags: %{}

  @typedoc "A node's zone decisions: per tag, whether it is in this zone and what is pending."
  @type t :: %__MODULE__{
          margin_db: number(),
          fast_db: number(),
          claim_db: number(),
          claim_dwell: pos_integer(),
          min_heard: pos_integer(),
          dwell: pos_integer(),
          exit_dwell: pos_integer(),
          exit_dbm: number(),
          exit_alone: boolean(),
          release_on_take: boolean(),
          far_dbm: number(),
          missing_rssi: number(),
          one_holder: boolean(),
          node: term(),
          neighbours: [term()],
          ledger: %{Beacon.tag_id() => {non_neg_integer(), :free | {:held, term()}}},
          intents: %{Beacon.tag_id() => [map()]},
          seen: MapSet.t(),
          out: [{term(), message()}],
          tags: %{
            Beacon.tag_id() => %{
              mine: boolean(),
              pending: nil | {atom(), number(), pos_integer()}
            }
          }
        }

  @typedoc """
  What a node says of one tag (`report/2`): `{rssi, held, heard}`: its RSSI of the tag,
  whether it holds the tag (`true`), is taking it from a neighbour (`:taking`: a hand-over
  under way) or neither (`false`), and whether it hears the tag well (the evidence rule, see
  the moduledoc). The older form `{rssi, held}` is accepted and counts as heard well.
  """
  @type report :: {number(), boolean() | :taking, boolean()} | {number(), boolean()}

  @typedoc """
  The neighbours' reports of one second: `%{neighbour => %{tag => report}}`, each
  neighbour's `report/2`.
  """
  @type reports :: %{term() => %{Beacon.tag_id() => report()}}

  @typedoc """
  A message of the one-holder protocol (`:one_holder`), sent to one neighbour: an ask to
  the holder, its give, a flooded ledger entry or claim intent (see "One holder per tag").
  """
  @type message ::
          {:zone, :ask, Beacon.tag_id(), term(), number(), number()}
          | {:zone, :give, Beacon.tag_id(), term(), number()}
          | {:zone, :ledger, Beacon.tag_id(), non_neg_integer(), :free | {:held, term()}}
          | {:zone, :intent, Beacon.tag_id(), map()}

  @typedoc "What the motion vectors are told."
  @type event ::
          {:entered_zone, Beacon.tag_id(), number()} | {:left_zone, Beacon.tag_id(), number()}

  @schema [
    margin_db: [
      type: :number,
      default: 6.0,
      doc: "how much stronger (dB) than the node holding a tag a neighbour must be to take it"
    ],
    fast_db: [
      type: :number,
      default: 12.0,
      doc:
        "a neighbour this much stronger (dB) than the holder takes the tag at once (a walker passing through a zone)"
    ],
    claim_db: [
      type: :number,
      default: 1.0,
      doc: "how much stronger (dB) than every neighbour a node must be to claim a tag"
    ],
    claim_dwell: [
      type: :pos_integer,
      default: 2,
      doc: "seconds a claim of a tag no neighbour holds must hold"
    ],
    min_heard: [
      type: :pos_integer,
      default: 3,
      doc: "samples a node must have heard in its tracker's window to claim a tag"
    ],
    dwell: [
      type: :pos_integer,
      default: 3,
      doc: "seconds a hand-over (a neighbour stronger by margin_db) must hold, on both sides"
    ],
    exit_dwell: [
      type: :pos_integer,
      default: 5,
      doc: "seconds a held tag must stay under the exit threshold to be released"
    ],
    calibration: [
      type: {:struct, Region},
      doc: "the near/far thresholds (default `TartarusLats.Region.calibrate/0`)"
    ],
    exit_db: [
      type: :number,
      default: 3.0,
      doc:
        "a held tag is out of range when its RSSI is this far (dB) under the far threshold (3 dB: about 1.4 times the far distance, 7 m with the default calibration)"
    ],
    exit_alone: [
      type: :boolean,
      default: false,
      doc:
        "a held tag is out of range only when every neighbour hears it under the exit threshold too (it is still in the building while a neighbour hears it)"
    ],
    release_on_take: [
      type: :boolean,
      default: false,
      doc:
        "a held tag is handed over only once the neighbour has taken it (reports holding it), not on the holder's own reading of the margin: a hand-over that one side sees and the other does not leaves the tag with its holder instead of with nobody"
    ],
    missing_rssi: [type: :number, default: -100, doc: "dBm of a tag a neighbour does not report"],
    one_holder: [
      type: :boolean,
      default: false,
      doc:
        "the one-holder protocol (see the moduledoc): at most one node holds a tag at the end of every second; needs `:node` and `:neighbours`, and the messages of `take_out/1` delivered (`deliver/3`) and `close/2` after them"
    ],
    node: [type: :any, doc: "this node's name (`:one_holder`)"],
    neighbours: [type: {:list, :any}, default: [], doc: "this node's neighbours (`:one_holder`)"]
  ]

  @doc """
  A node's zone decision. Options:

  #{Tartarus.Options.docs(@schema)}

  Raises `ArgumentError` naming the key on a bad option.

      iex> TartarusLats.Zone.new(dwell: 0)
      ** (ArgumentError) invalid options given to TartarusLats.Zone.new/1 for key :dwell: expected a positive integer, got: 0
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    opts = Tartarus.Options.validate!(opts, @schema, "TartarusLats.Zone.new/1")

    if opts[:margin_db] < opts[:claim_db] or opts[:claim_db] < 0 or
         opts[:fast_db] < opts[:margin_db],
       do:
         raise(
           ArgumentError,
           "invalid options given to TartarusLats.Zone.new/1: expected 0 <= claim_db <= margin_db <= fast_db, got: claim_db: #{opts[:claim_db]}, margin_db: #{opts[:margin_db]}, fast_db: #{opts[:fast_db]}"
         )

    cal = Keyword.get_lazy(opts, :calibration, fn -> Region.calibrate() end)

    %__MODULE__{
      margin_db: opts[:margin_db],
      fast_db: opts[:fast_db],
      claim_db: opts[:claim_db],
      claim_dwell: opts[:claim_dwell],
      min_heard: opts[:min_heard],
      dwell: opts[:dwell],
      exit_dwell: opts[:exit_dwell],
      exit_dbm: cal.far_dbm - opts[:exit_db],
      exit_alone: opts[:exit_alone],
      release_on_take: opts[:release_on_take],
      far_dbm: cal.far_dbm,
      missing_rssi: opts[:missing_rssi],
      one_holder: opts[:one_holder],
      node: opts[:node],
      neighbours: Enum.sort(opts[:neighbours])
    }
  end

  @doc """
  Decides second `t` for every tag this node hears or holds: `tracker` is this node's
  tracker after second `t`, `reports` its neighbours' filtered RSSI of second `t`. Returns
  the events, sorted by tag, and the new decision state.
  """
  @spec decide(t(), number(), Tracker.t(), reports()) :: {[event()], t()}
  def decide(%__MODULE__{} = z, t, %Tracker{} = tracker, reports) when is_map(reports) do
    z = if z.one_holder, do: proxy_releases(%{z | seen: MapSet.new()}, reports), else: z
    held = for {tag, %{mine: true}} <- z.tags, do: tag
    tags = Enum.sort(Enum.uniq(Tracker.tags(tracker) ++ held))

    {events, z} =
      Enum.reduce(tags, {[], z}, fn tag, {events, z} ->
        state = Map.get(z.tags, tag, %{mine: false, pending: nil})
        own = Tracker.heard_average(tracker, tag) || z.missing_rssi

        heard =
          cond do
            Tracker.heard_count(tracker, tag) < z.min_heard -> :none
            not heard?(z, tracker, tag) -> :weak
            in_range?(z, tracker, tag) -> :in_range
            true -> :heard
          end

        n = n(z, reports, tag)
        {event, new} = step(z, t, tag, state, heard, own, n)

        {event, new, z} =
          if z.one_holder, do: protocol(z, tag, state, new, event, own, n), else: {event, new, z}

        {if(event, do: [event | events], else: events), %{z | tags: store(z.tags, tag, new)}}
      end)

    {Enum.reverse(events), z}
  end

  # -- one holder per tag (`:one_holder`) -----------------------------------------------

  # What the rule of a second decided, put through the protocol: a claim becomes an intent
  # (flooded, arbitrated at `close/2`) when the ledger says the tag is free, and nothing
  # when it says another node holds it (the claimant is no neighbour of the holder: it
  # waits for the release); a take becomes an ask to the holder (who gives at the next
  # delivery); a release out of range is flooded as a ledger entry. A held tag is never let
  # go on this node's reading of a neighbour's margin: only given, or released.
  defp protocol(z, tag, old, new, {:entered_zone, tag, since}, own, n) do
    back = %{new | mine: false, pending: old_pending(old, since)}

    cond do
      n.holder_node != nil ->
        {nil, back, send_to(z, n.holder_node, {:zone, :ask, tag, z.node, own, since})}

      free?(z, tag) ->
        intent = %{node: z.node, rssi: own, since: since, epoch: epoch(z, tag)}
        z = %{z | intents: Map.update(z.intents, tag, [intent], &[intent | &1])}
        {nil, back, flood(z, {:zone, :intent, tag, intent})}

      true ->
        {nil, %{new | mine: false, pending: nil}, z}
    end
  end

  defp protocol(z, tag, _old, new, {:left_zone, tag, _since} = event, _own, _n) do
    {event, new, set_ledger(z, tag, {epoch(z, tag) + 1, :free}, true)}
  end

  defp protocol(z, _tag, _old, new, nil, _own, _n), do: {nil, new, z}

  # A claim or take asked for goes on as pending, so that it is asked again next second if
  # its condition still holds (and it was not granted).
  defp old_pending(%{pending: {why, since, count}}, _since) when why in [:take, :claim],
    do: {why, since, count}

  defp old_pending(_old, since), do: {:take, since, 1}

  defp free?(z, tag), do: match?({_, :free}, Map.get(z.ledger, tag, {0, :free}))
  defp epoch(z, tag), do: z.ledger |> Map.get(tag, {0, :free}) |> elem(0)

  # A neighbour the ledger says holds a tag, whose report does not say it holds it, is
  # gone (a live holder always reports what it holds): its neighbours release the tag for it.
  defp proxy_releases(z, reports) do
    Enum.reduce(Enum.sort(z.ledger), z, fn
      {tag, {e, {:held, h}}}, z when h != z.node ->
        if h in z.neighbours and not match?(%{^tag => {_, true, _}}, Map.get(reports, h, %{})) and
             not match?(%{^tag => {_, true}}, Map.get(reports, h, %{})),
           do: set_ledger(z, tag, {e + 1, :free}, true),
           else: z

      _, z ->
        z
    end)
  end

  defp set_ledger(z, tag, entry, flood?) do
    z = %{z | ledger: Map.put(z.ledger, tag, entry)}
    if flood?, do: flood(z, {:zone, :ledger, tag, elem(entry, 0), elem(entry, 1)}), else: z
  end

  defp send_to(z, node, msg), do: %{z | out: [{node, msg} | z.out]}
  defp flood(z, msg), do: Enum.reduce(z.neighbours, z, &send_to(&2, &1, msg))

  @doc """
  The protocol messages this node has to send (`:one_holder`), as `[{neighbour,
  message}]` in the order made, and the state without them. Empty without `:one_holder`.
  """
  @spec take_out(t()) :: {[{term(), message()}], t()}
  def take_out(%__MODULE__{out: out} = z), do: {Enum.reverse(out), %{z | out: []}}

  @doc """
  Applies the protocol messages that reached this node in one delivery of second `t`
  (`:one_holder`): asks (the holder gives the tag to the strongest asker, ties by the
  earlier take then the name, and lets it go), gives (this node holds the tag), ledger
  entries (a newer one is kept and passed on) and claim intents (kept for `close/2`,
  passed on once; an intent made on an older ledger than this node's is answered with the
  ledger entry). Returns the zone events and the new state; messages to send are in
  `take_out/1`.
  """
  @spec deliver(t(), number(), [message()]) :: {[event()], t()}
  def deliver(%__MODULE__{} = z, _t, msgs) do
    {asks, rest} = Enum.split_with(msgs, &match?({:zone, :ask, _, _, _, _}, &1))
    {events, z} = Enum.reduce(Enum.sort(rest), {[], z}, &receive_one/2)

    {more, z} =
      asks
      |> Enum.group_by(&elem(&1, 2))
      |> Enum.sort()
      |> Enum.reduce({[], z}, fn {tag, tag_asks}, {events, z} ->
        if holds?(z, tag) do
          {:zone, :ask, _, to, _rssi, since} =
            Enum.min_by(tag_asks, fn {:zone, :ask, _, from, rssi, since} ->
              {-rssi, since, from}
            end)

          z = %{z | tags: Map.delete(z.tags, tag)}
          z = send_to(z, to, {:zone, :give, tag, z.node, since})
          z = set_ledger(z, tag, {epoch(z, tag) + 1, {:held, to}}, true)
          {[{:left_zone, tag, since} | events], z}
        else
          {events, z}
        end
      end)

    {Enum.reverse(events) ++ Enum.reverse(more), z}
  end

  defp receive_one({:zone, :give, tag, _from, since}, {events, z}) do
    {[{:entered_zone, tag, since} | events],
     %{z | tags: Map.put(z.tags, tag, %{mine: true, pending: nil})}}
  end

  defp receive_one({:zone, :ledger, tag, e, state}, {events, z}) do
    if e > epoch(z, tag), do: {events, set_ledger(z, tag, {e, state}, true)}, else: {events, z}
  end

  defp receive_one({:zone, :intent, tag, intent}, {events, z}) do
    key = {tag, intent.node}

    cond do
      MapSet.member?(z.seen, key) or intent.node == z.node ->
        {events, z}

      true ->
        z = %{
          z
          | seen: MapSet.put(z.seen, key),
            intents: Map.update(z.intents, tag, [intent], &[intent | &1])
        }

        z = flood(z, {:zone, :intent, tag, intent})
        # The claimant's ledger is older than this node's: tell it (and whoever else) the news.
        z =
          if intent.epoch < epoch(z, tag),
            do: flood(z, {:zone, :ledger, tag, epoch(z, tag), elem(z.ledger[tag], 1)}),
            else: z

        {events, z}
    end
  end

  defp receive_one(_other, acc), do: acc

  @doc """
  Ends second `t` (`:one_holder`), once every message of the second is delivered: the claim
  intents of the second are arbitrated, the same way on every node (they all saw the same
  intents and hold the same ledger): when the ledger says the tag is free, the intent with
  the strongest RSSI (ties: the earlier claim, then the node's name) wins and that node
  holds the tag; intents made on an older ledger count for nothing. Returns this node's
  zone events and the new state.
  """
  @spec close(t(), number()) :: {[event()], t()}
  def close(%__MODULE__{} = z, _t) do
    {events, z} =
      z.intents
      |> Enum.sort()
      |> Enum.reduce({[], z}, fn {tag, intents}, {events, z} ->
        e = epoch(z, tag)
        valid = Enum.filter(intents, &(&1.epoch == e))

        case free?(z, tag) and valid != [] do
          true ->
            w = Enum.min_by(valid, &{-&1.rssi, &1.since, &1.node})
            z = set_ledger(z, tag, {e + 1, {:held, w.node}}, false)

            if w.node == z.node,
              do:
                {[{:entered_zone, tag, w.since} | events],
                 %{z | tags: Map.put(z.tags, tag, %{mine: true, pending: nil})}},
              else: {events, %{z | tags: lost(z.tags, tag)}}

          false ->
            {events, %{z | tags: lost(z.tags, tag)}}
        end
      end)

    {Enum.reverse(events), %{z | intents: %{}}}
  end

  defp lost(tags, tag) do
    case tags do
      %{^tag => %{mine: false}} -> Map.delete(tags, tag)
      _ -> tags
    end
  end

  @doc "Who this node's ledger says holds `tag` (`:one_holder`): a node, or nil (free)."
  @spec ledger_holder(t(), Beacon.tag_id()) :: term() | nil
  def ledger_holder(%__MODULE__{ledger: ledger}, tag) do
    case ledger do
      %{^tag => {_, {:held, h}}} -> h
      _ -> nil
    end
  end

  @doc """
  What this node tells its neighbours after second `t`: `%{tag => {rssi, held, heard}}` for
  every tag it hears or holds (`rssi` is `TartarusLats.Tracker.heard_average/2`, or the
  floor; see `t:report/0`).
  """
  @spec report(t(), Tracker.t()) :: %{Beacon.tag_id() => report()}
  def report(%__MODULE__{} = z, %Tracker{} = tracker) do
    tags = Enum.uniq(Tracker.tags(tracker) ++ held(z))

    Map.new(tags, fn tag ->
      held =
        case z.tags do
          %{^tag => %{mine: true}} -> true
          %{^tag => %{pending: {:take, _, _}}} -> :taking
          _ -> false
        end

      {tag,
       {Tracker.heard_average(tracker, tag) || z.missing_rssi, held, heard?(z, tracker, tag)}}
    end)
  end

  # The evidence that a node hears a tag well, the same for a take, a release and what a
  # neighbour's report counts for: `min_heard` samples heard in the window, and an RSSI (the
  # mean of the samples heard) at or above the far threshold.
  defp heard?(z, tracker, tag) do
    (Tracker.heard_average(tracker, tag) || z.missing_rssi) >= z.far_dbm and
      Tracker.heard_count(tracker, tag) >= z.min_heard
  end

  # A claim (no neighbour holds the tag: it comes from nowhere) needs the evidence to be in
  # range itself: `min_heard` samples at or above the far threshold, not a mean that a
  # burst of fewer loud samples can lift above it.
  defp in_range?(z, tracker, tag),
    do: Tracker.heard_count(tracker, tag, z.far_dbm) >= z.min_heard

  @doc "True if this node holds `tag` in its zone."
  @spec holds?(t(), Beacon.tag_id()) :: boolean()
  def holds?(%__MODULE__{tags: tags}, tag), do: match?(%{^tag => %{mine: true}}, tags)

  @doc "The tags this node holds in its zone, sorted."
  @spec held(t()) :: [Beacon.tag_id()]
  def held(%__MODULE__{tags: tags}), do: Enum.sort(for {tag, %{mine: true}} <- tags, do: tag)

  # Not held. With no neighbour holding or taking the tag: claim once heard, stronger than
  # every neighbour by claim_db, for claim_dwell seconds. With a neighbour holding it: take
  # it once heard and stronger than the holder by margin_db for `dwell` seconds (fast_db:
  # at once) and than every other neighbour taking it by claim_db; a neighbour that is
  # stronger but neither holds nor takes the tag does not stop a hand-over under way (a
  # walker passing through this zone is already nearer the next one: this node takes the
  # tag, and the next one takes it from here). With a neighbour taking it from a holder this
  # node does not see: wait for that hand-over (then take it from the new holder).
  defp step(z, t, tag, %{mine: false} = state, heard, own, n) do
    cond do
      heard == :none or (heard == :weak and not taking?(state, n)) ->
        {nil, %{state | pending: nil}}

      n.holder == nil and n.taker != nil ->
        {nil, %{state | pending: nil}}

      n.holder == nil ->
        if heard == :in_range and own >= n.best + z.claim_db,
          do: hold(state, t, {:claim, z.claim_dwell}, {:entered_zone, tag}, true),
          else: {nil, %{state | pending: nil}}

      n.taker != nil and own < n.taker + z.claim_db ->
        {nil, %{state | pending: nil}}

      own >= n.holder + z.fast_db ->
        hold(state, t, {:take, 1}, {:entered_zone, tag}, true)

      own >= n.holder + z.margin_db ->
        hold(state, t, {:take, z.dwell}, {:entered_zone, tag}, true)

      passed_on?(z, state, own, n) ->
        {{:entered_zone, tag, elem(state.pending, 1)}, %{mine: true, pending: nil}}

      true ->
        {nil, %{state | pending: nil}}
    end
  end

  # Held: release when a neighbour that hears the tag well (the evidence rule) is stronger
  # by margin_db for `dwell` seconds (it takes the tag), or when out of range (under the
  # exit threshold) for `exit_dwell` seconds. A neighbour that holds the tag too (it took
  # it on a walker passing through, see passed_on?/4) and hears it more strongly by
  # claim_db has it: let go at once.
  defp step(z, t, tag, %{mine: true} = state, _heard, own, n) do
    cond do
      n.holder != nil and n.holder >= own + z.claim_db and not z.one_holder ->
        hold(state, t, {:handed, 1}, {:left_zone, tag}, false)

      n.evident >= own + z.fast_db and not (z.release_on_take or z.one_holder) ->
        hold(state, t, {:handed, 1}, {:left_zone, tag}, false)

      n.evident >= own + z.margin_db and not (z.release_on_take or z.one_holder) ->
        hold(state, t, {:handed, z.dwell}, {:left_zone, tag}, false)

      own < z.exit_dbm and not (z.exit_alone and n.best >= z.exit_dbm) ->
        hold(state, t, {:exit, z.exit_dwell}, {:left_zone, tag}, false)

      true ->
        {nil, %{state | pending: nil}}
    end
  end

  # A take under way goes on while this node still hears the tag (`min_heard` samples) and
  # the holder is still held, even if the mean dips under the far threshold: a walker
  # passing through a zone at 2.5 m/s is within its far range for 3-4 s only.
  defp taking?(%{pending: {:take, _, _}}, %{holder: holder}), do: holder != nil
  defp taking?(_state, _n), do: false

  # A take under way that loses its margin over the holder before `dwell` seconds, because
  # the walker has passed through this zone on to the next, completes now (dated from its
  # first second) so that the chain of zones does not break here: the holder no longer
  # hears the tag well, this node is still nearer it than the holder (claim_db), and a
  # neighbour that neither holds nor takes it hears it well and at least as strongly as
  # this node (the walker is past the middle of this zone; 1 dB more was too much for a
  # 2 m/s walker that the next node heard 0.4 dB more strongly in the second the take was
  # cut). That neighbour then takes the tag from here by the usual rule, and the
  # old holder, seeing this node hold it more strongly, lets go. Without it the next node
  # claimed the tag from nowhere and the holder let it go to nobody (`:left_building`).
  # Evidence as for any take: this node heard the tag well (or went on taking it) for every
  # second of the take, and the neighbour ahead hears it well; a burst at a node no
  # neighbour of the holder can take nothing, and a standing tag is heard well by its holder.
  defp passed_on?(z, %{pending: {:take, _, _}}, own, n) do
    n.holder != nil and not n.holder_heard and own >= n.holder + z.claim_db and
      n.ahead >= own
  end

  defp passed_on?(_z, _state, _own, _n), do: false

  # A condition (`why`) that must hold `need` consecutive seconds; the event is dated from
  # its first second. A different condition starts the count again.
  defp hold(state, t, {why, need}, {kind, tag}, mine_after) do
    {since, count} =
      case state.pending do
        {^why, since, count} -> {since, count + 1}
        _ -> {t, 1}
      end

    if count >= need,
      do: {{kind, tag, since}, %{mine: mine_after, pending: nil}},
      else: {nil, %{state | pending: {why, since, count}}}
  end

  # What the neighbours say of the tag: the strongest RSSI (`best`), the strongest of those
  # that hear it well (`evident`, the floor if none does), the RSSI of the neighbour that
  # holds it and of the strongest one taking it (nil if none). A report of the older form
  # `{rssi, held}` counts as heard well.
  defp n(z, reports, tag) do
    init = %{
      best: z.missing_rssi,
      evident: z.missing_rssi,
      ahead: z.missing_rssi,
      holder: nil,
      holder_node: nil,
      holder_heard: false,
      taker: nil
    }

    reports
    |> Enum.sort()
    |> Enum.reduce(init, fn {node, values}, acc ->
      case values do
        %{^tag => {v, held}} when is_number(v) ->
          count(acc, v, held, true) |> holder_node(node, held)

        %{^tag => {v, held, heard}} when is_number(v) ->
          count(acc, v, held, heard == true) |> holder_node(node, held)

        _ ->
          acc
      end
    end)
  end

  defp holder_node(%{holder_node: nil} = acc, node, true), do: %{acc | holder_node: node}
  defp holder_node(acc, _node, _held), do: acc

  defp count(acc, v, held, heard) do
    acc = %{acc | best: max(acc.best, v)}
    acc = if heard, do: %{acc | evident: max(acc.evident, v)}, else: acc

    case held do
      true -> %{acc | holder: max(acc.holder || v, v), holder_heard: acc.holder_heard or heard}
      :taking -> %{acc | taker: max(acc.taker || v, v)}
      _ when heard -> %{acc | ahead: max(acc.ahead, v)}
      _ -> acc
    end
  end

  # Nothing to remember about a tag that is not held and has nothing pending.
  defp store(states, tag, %{mine: false, pending: nil}), do: Map.delete(states, tag)
  defp store(states, tag, state), do: Map.put(states, tag, state)
end
