defmodule TartarusLats.MotionVectors do
  @moduledoc """
  A node's motion vectors (thesis §3.3.4, Table 3.1) and the handshake that sets them.

  Each node keeps, per tag, two vectors:

    * **MVB** (backward) `{from, here}` - where the tag came from;
      `{:infinity, here}` when it entered the building here;
    * **MVF** (forward) `{here, to}` - where it went; `{here, here}` while it
      is still here (presence); `{here, :infinity}` when it left the building
      from here.

  (Table 3.1 prints Py's MVF as `Z_Py -> Z_Px`; the text says `Z_Py -> Z_Py`,
  the presence indicator. We follow the text.)

  The table is a plain value owned by the node's database agent. It is
  driven by `handle/3`, which takes an event and returns the new table and
  the messages to send; the agent only delivers them. The events are exactly
  what `TartarusLats.Tracker` emits plus the two handshake messages:

  | event                                        | from                   |
  |----------------------------------------------|------------------------|
  | `{:entered_zone, tag, t}`                    | this node's tracker    |
  | `{:left_zone, tag, t}`                       | this node's tracker    |
  | `{:leaving, tag, px, t_left, px_arrived}`    | neighbour `px`         |
  | `{:ack, tag, py, t_left, t_arrived}`         | neighbour `py`         |
  | `:tick`                                      | a 1 s timer            |

  and the actions are `{:broadcast, message}` (send to every neighbour) and
  `{:send, node, message}`.

  ## The handshake

  When the tag goes far -> beyond at `px` (`:left_zone`), `px` marks MVF
  `{px, :pending}` and broadcasts `{:leaving, tag, px, t_left, px_arrived}`
  (`px_arrived`: when this stay at `px` began). A neighbour `py` that has
  the tag in its zone (now, or within `timeout` seconds of the notice,
  because zones overlap and either node may notice first) sets
  MVB = `{px, py}`, MVF = `{py, py}` and answers
  `{:ack, tag, py, t_left, t_arrived}`; `px` then sets MVF = `{px, py}`.

  A neighbour only acknowledges a stay that began *after* `px_arrived`: if
  `py` has had the tag since before `px` saw it, `px`'s stay was an overlap
  (or noise) inside `py`'s stay, not a move to `py`, and `py` stays silent.
  When several notices wait for the same tag, the latest departure (then
  the latest stay) is taken as the origin.

  Timeouts (default 15 s, option `:timeout`), checked on `:tick`:

    * **exit**: no neighbour acknowledged within `timeout` of `t_left`:
      MVF = `{px, :infinity}`. The thesis says INFINITY means "not traceable
      at any zone", i.e. the tag left the instrumented building; a neighbour
      that never acknowledges (down, or its receiver missed the tag) looks
      the same, and we say so rather than guess.
    * **entry**: a tag appeared here and no neighbour announced its leaving
      within `timeout`: MVB = `{:infinity, py}` (it came in from outside).

  Both decisions are corrected if the missing message arrives late while
  the segment is still current: a late ack replaces `:infinity` in MVF, a
  late notice for a tag still present replaces `:infinity` in MVB. While
  undecided, the vectors read `{px, :pending}` / `{:pending, py}`: a query
  agent should wait a second and look again.

  If the tag comes back into `px`'s zone before anyone acknowledged, `px`
  records a loop (MVF `{px, px}` for the old stay, MVB `{px, px}` for the
  new one); `trace/3` merges such consecutive stays.

  A notice also resolves the origin of a stay that already ended, if that
  origin is still `:pending` (the tag passed through this zone faster than
  the previous zone noticed it leaving).

  Known limit: noise can make a node see a tag for a few seconds that never
  left a neighbour's zone (a "ghost" stay). Nobody acknowledges it, so it
  reads as entered from and left to INFINITY; it does not break the chain
  of the real stays, but a trace *started* at that node begins there.

  ## History

  Besides the current vectors the table keeps every stay ("segment") of
  every tag at this node, newest first: arrived at `arrived_at` from `from`
  (who left at `from_left_at`), left at `left_at` to `to` (who saw it
  arrive at `to_arrived_at`). The two timestamps link a stay to the
  neighbouring node's stay exactly, so a trace is correct even when a tag
  visits the same node many times. `trace/3` follows those links over a map
  of tables (what a Trace agent does hop by hop; thesis Algorithm 1).

  ## Example: a tag enters at `:a` and walks to `:b`

      iex> alias TartarusLats.MotionVectors, as: MV
      iex> tag = {"00000000000000000000000000000001", 1, 1}
      iex> a = MV.new(:a)
      iex> b = MV.new(:b)
      iex> {a, []} = MV.handle(a, 0, {:entered_zone, tag, 0})
      iex> {a, []} = MV.handle(a, 15, :tick)
      iex> {MV.mvb(a, tag), MV.mvf(a, tag)}
      {{:infinity, :a}, {:a, :a}}
      iex> {a, [{:broadcast, notice}]} = MV.handle(a, 40, {:left_zone, tag, 40})
      iex> MV.mvf(a, tag)
      {:a, :pending}
      iex> {b, []} = MV.handle(b, 40, notice)
      iex> {b, [{:send, :a, ack}]} = MV.handle(b, 42, {:entered_zone, tag, 41})
      iex> {a, []} = MV.handle(a, 42, ack)
      iex> {MV.mvf(a, tag), MV.mvb(b, tag), MV.mvf(b, tag)}
      {{:a, :b}, {:a, :b}, {:b, :b}}
  """

  alias TartarusLats.Beacon

  defstruct node: nil, timeout: 15, tags: %{}, notices: %{}, waiting: %{}

  @typedoc "A node name (any term; the emulated building uses atoms like `:p7`)."
  @type node_name :: term()

  @typedoc "An end of a vector: a node, outside the building, or not yet known."
  @type endpoint :: node_name() | :infinity | :pending

  @typedoc "A motion vector `{from, to}`."
  @type vector :: {endpoint(), endpoint()}

  @typedoc """
  One stay of a tag at this node. `to` is `nil` while the tag is here.
  """
  @type segment :: %{
          arrived_at: number(),
          from: endpoint(),
          from_left_at: number() | nil,
          left_at: number() | nil,
          to: endpoint() | nil,
          to_arrived_at: number() | nil
        }

  @typedoc "Handshake messages between neighbouring nodes."
  @type message ::
          {:leaving, Beacon.tag_id(), node_name(), number(), number()}
          | {:ack, Beacon.tag_id(), node_name(), number(), number()}

  @type event ::
          {:entered_zone, Beacon.tag_id(), number()}
          | {:left_zone, Beacon.tag_id(), number()}
          | message()
          | :tick

  @type action :: {:broadcast, message()} | {:send, node_name(), message()}

  @type t :: %__MODULE__{
          node: node_name(),
          timeout: pos_integer(),
          tags: %{Beacon.tag_id() => [segment()]},
          notices: %{Beacon.tag_id() => [{node_name(), number(), number(), number()}]},
          waiting: %{{Beacon.tag_id(), :arrival | :departure, number()} => number()}
        }

  @typedoc "Result of `trace/3`."
  @type trace :: %{
          path: [%{node: node_name(), arrived_at: number(), left_at: number() | nil}],
          entry: :infinity | :pending | :broken,
          status: :present | :exited | :in_transit | :broken
        }

  @doc """
  An empty table for node `node`. Option `:timeout` (seconds, default 15).

      iex> TartarusLats.MotionVectors.new(:p1, timeout: 0)
      ** (ArgumentError) invalid options given to TartarusLats.MotionVectors.new/2 for key :timeout: expected a positive number, got: 0
  """
  @spec new(node_name(), keyword()) :: t()
  def new(node, opts \\ []) do
    schema = [
      timeout: [
        type: :any,
        default: 15,
        check: :positive,
        doc: "handshake timeout in seconds"
      ]
    ]

    opts = TartarusLats.Options.validate!(opts, schema, "TartarusLats.MotionVectors.new/2")
    %__MODULE__{node: node, timeout: opts[:timeout]}
  end

  @doc """
  Applies one event at time `now`; returns the new table and the messages to send.

  See the moduledoc for the events and the handshake. Unknown or stale
  messages (an ack for a stay already linked, a notice for a tag this node
  never sees) change nothing and produce no action.
  """
  @spec handle(t(), number(), event()) :: {t(), [action()]}
  def handle(%__MODULE__{} = mv, now, event) when is_number(now) do
    do_handle(mv, now, event)
  end

  defp do_handle(mv, _now, {:entered_zone, tag, t}) do
    here = mv.node

    case segments(mv, tag) do
      [%{to: nil} | _] ->
        {mv, []}

      [%{to: :pending} = last | rest] ->
        # Came back before any neighbour saw it: a loop here -> here.
        closed = %{last | to: here, to_arrived_at: t}
        stay = new_segment(t, here, last.left_at)

        mv =
          mv
          |> put_segments(tag, [stay, closed | rest])
          |> unwait({tag, :departure, last.left_at})

        {mv, []}

      list ->
        case take_notice(mv, tag) do
          {{px, t_left}, mv} ->
            mv = put_segments(mv, tag, [new_segment(t, px, t_left) | list])
            {mv, [{:send, px, {:ack, tag, here, t_left, t}}]}

          {nil, mv} ->
            mv =
              mv
              |> put_segments(tag, [new_segment(t, :pending, nil) | list])
              |> wait({tag, :arrival, t}, t + mv.timeout)

            {mv, []}
        end
    end
  end

  defp do_handle(mv, _now, {:left_zone, tag, t}) do
    case segments(mv, tag) do
      [%{to: nil} = stay | rest] ->
        mv =
          mv
          |> put_segments(tag, [%{stay | left_at: t, to: :pending} | rest])
          |> wait({tag, :departure, t}, t + mv.timeout)

        {mv, [{:broadcast, {:leaving, tag, mv.node, t, stay.arrived_at}}]}

      _ ->
        {mv, []}
    end
  end

  defp do_handle(mv, now, {:leaving, tag, px, t_left, px_arrived}) do
    case segments(mv, tag) do
      [%{to: nil, arrived_at: arrived} = stay | rest] when arrived > px_arrived ->
        case loop_root(mv.node, [stay | rest]) do
          {newer, %{from: from, arrived_at: root_arrived} = root, older}
          when from in [:pending, :infinity] and root_arrived > px_arrived ->
            # The stay here (possibly a chain of stays joined by short
            # excursions out of range, here -> here) has no known origin:
            # px is it. Link the chain's first stay, so that the chain
            # stays whole and a short first stay is not left as a ghost.
            mv =
              mv
              |> put_segments(tag, newer ++ [%{root | from: px, from_left_at: t_left} | older])
              |> unwait({tag, :arrival, root_arrived})

            {mv, [{:send, px, {:ack, tag, mv.node, t_left, root_arrived}}]}

          _ ->
            {mv, [{:send, px, {:ack, tag, mv.node, t_left, arrived}}]}
        end

      [%{to: nil} | _] ->
        # We had the tag before px did and still have it: px's stay was an
        # overlap (or a ghost) inside ours, not a move to us.
        {mv, []}

      [%{from: :pending, to: to, arrived_at: arrived} = stay | rest]
      when arrived > px_arrived and to != px ->
        # The tag passed through here faster than px noticed it leaving.
        mv = link_from(mv, tag, stay, rest, px, t_left)
        {mv, [{:send, px, {:ack, tag, mv.node, t_left, arrived}}]}

      _ ->
        notice = {px, t_left, px_arrived, now}
        {%{mv | notices: Map.update(mv.notices, tag, [notice], &[notice | &1])}, []}
    end
  end

  defp do_handle(mv, _now, {:ack, tag, py, t_left, t_arrived}) do
    list = segments(mv, tag)

    case Enum.split_while(list, &(&1.left_at != t_left)) do
      {before, [%{to: to} = stay | rest]} when to in [:pending, :infinity] ->
        stay = %{stay | to: py, to_arrived_at: t_arrived}

        mv =
          mv
          |> put_segments(tag, before ++ [stay | rest])
          |> unwait({tag, :departure, t_left})

        {mv, []}

      _ ->
        {mv, []}
    end
  end

  defp do_handle(mv, now, :tick) do
    {expired, waiting} = Enum.split_with(mv.waiting, fn {_key, deadline} -> deadline <= now end)
    mv = %{mv | waiting: Map.new(waiting)}

    mv =
      expired
      |> Enum.map(&elem(&1, 0))
      |> Enum.sort()
      |> Enum.reduce(mv, &expire/2)

    notices =
      for {tag, list} <- mv.notices,
          kept = Enum.filter(list, fn {_, _, _, received} -> now - received < mv.timeout end),
          kept != [],
          into: %{},
          do: {tag, kept}

    {%{mv | notices: notices}, []}
  end

  defp do_handle(_mv, _now, event) do
    raise ArgumentError,
          "invalid event given to TartarusLats.MotionVectors.handle/3: #{inspect(event)}"
  end

  # Splits a newest-first list of stays into the chain of stays joined by
  # here -> here loops that ends with the newest one: `{newer, root, older}`
  # where `root` is the chain's first stay.
  defp loop_root(here, [stay | rest]), do: loop_root(here, stay, rest, [])

  defp loop_root(
         here,
         %{from: here, from_left_at: t} = stay,
         [%{to: here, left_at: t} = prev | rest],
         acc
       ),
       do: loop_root(here, prev, rest, acc ++ [stay])

  defp loop_root(_here, stay, rest, acc), do: {acc, stay, rest}

  defp link_from(mv, tag, stay, rest, px, t_left) do
    mv
    |> put_segments(tag, [%{stay | from: px, from_left_at: t_left} | rest])
    |> unwait({tag, :arrival, stay.arrived_at})
  end

  defp expire({tag, :arrival, t}, mv) do
    update_segment(
      mv,
      tag,
      &(&1.arrived_at == t and &1.from == :pending),
      &%{&1 | from: :infinity}
    )
  end

  defp expire({tag, :departure, t}, mv) do
    update_segment(mv, tag, &(&1.left_at == t and &1.to == :pending), &%{&1 | to: :infinity})
  end

  defp update_segment(mv, tag, match, fun) do
    put_segments(mv, tag, Enum.map(segments(mv, tag), &if(match.(&1), do: fun.(&1), else: &1)))
  end

  defp new_segment(t, from, from_left_at) do
    %{
      arrived_at: t,
      from: from,
      from_left_at: from_left_at,
      left_at: nil,
      to: nil,
      to_arrived_at: nil
    }
  end

  defp take_notice(mv, tag) do
    case Map.pop(mv.notices, tag) do
      {[_ | _] = list, notices} ->
        {px, t_left, _, _} =
          Enum.max_by(list, fn {_, t_left, arrived, _} -> {t_left, arrived} end)

        {{px, t_left}, %{mv | notices: notices}}

      {nil, _} ->
        {nil, mv}
    end
  end

  defp put_segments(mv, tag, list), do: %{mv | tags: Map.put(mv.tags, tag, list)}
  defp wait(mv, key, deadline), do: %{mv | waiting: Map.put(mv.waiting, key, deadline)}
  defp unwait(mv, key), do: %{mv | waiting: Map.delete(mv.waiting, key)}

  @doc """
  The stays of `tag` at this node, newest first (`[]` if never seen).
  """
  @spec segments(t(), Beacon.tag_id()) :: [segment()]
  def segments(%__MODULE__{tags: tags}, tag), do: Map.get(tags, tag, [])

  @doc "The tags this node has ever seen, sorted."
  @spec tags(t()) :: [Beacon.tag_id()]
  def tags(%__MODULE__{tags: tags}), do: tags |> Map.keys() |> Enum.sort()

  @doc """
  Motion Vector Forward of `tag` here (thesis): `{here, here}` if present,
  `{here, next}`, `{here, :infinity}`, `{here, :pending}`; `nil` if never seen.
  """
  @spec mvf(t(), Beacon.tag_id()) :: vector() | nil
  def mvf(%__MODULE__{node: here} = mv, tag) do
    case segments(mv, tag) do
      [] -> nil
      [%{to: nil} | _] -> {here, here}
      [%{to: to} | _] -> {here, to}
    end
  end

  @doc """
  Motion Vector Backward of `tag` here: `{previous, here}`,
  `{:infinity, here}` or `{:pending, here}`; `nil` if never seen.
  """
  @spec mvb(t(), Beacon.tag_id()) :: vector() | nil
  def mvb(%__MODULE__{node: here} = mv, tag) do
    case segments(mv, tag) do
      [] -> nil
      [%{from: from} | _] -> {from, here}
    end
  end

  @doc "Whether `tag` is currently in this node's zone (its MVF is `{here, here}`)."
  @spec present?(t(), Beacon.tag_id()) :: boolean()
  def present?(mv, tag), do: match?([%{to: nil} | _], segments(mv, tag))

  @doc "The stay of `tag` that began at `arrived_at`, or `nil`."
  @spec arrival(t(), Beacon.tag_id(), number()) :: segment() | nil
  def arrival(mv, tag, arrived_at),
    do: Enum.find(segments(mv, tag), &(&1.arrived_at == arrived_at))

  @doc "The stay of `tag` that ended at `left_at`, or `nil`."
  @spec departure(t(), Beacon.tag_id(), number()) :: segment() | nil
  def departure(mv, tag, left_at), do: Enum.find(segments(mv, tag), &(&1.left_at == left_at))

  @doc """
  Drops closed stays that ended before `before` (seconds), to bound memory.

  A trace that needs a dropped stay ends with `:broken` there.
  """
  @spec prune(t(), number()) :: t()
  def prune(%__MODULE__{} = mv, before) do
    tags =
      for {tag, list} <- mv.tags,
          kept =
            Enum.reject(
              list,
              &(is_number(&1.left_at) and &1.left_at < before and &1.to != :pending)
            ),
          kept != [],
          into: %{},
          do: {tag, kept}

    %{mv | tags: tags}
  end

  @doc """
  Reconstructs the path of `tag` through the visit that includes `start`'s
  latest stay, following MVB links back to the entry and MVF links forward
  to the end, over `tables` (a map node => table).

  Consecutive stays at the same node (a tag that stepped out of range and
  came back) are merged. Returns `{:error, :no_trace}` if `start` never saw
  the tag or `start` is not in `tables`.

      iex> alias TartarusLats.MotionVectors, as: MV
      iex> tag = {"00000000000000000000000000000001", 1, 1}
      iex> {a, _} = MV.new(:a) |> MV.handle(0, {:entered_zone, tag, 0})
      iex> {a, _} = MV.handle(a, 15, :tick)
      iex> MV.trace(%{a: a}, :a, tag)
      {:ok, %{path: [%{node: :a, arrived_at: 0, left_at: nil}], entry: :infinity, status: :present}}
  """
  @spec trace(%{node_name() => t()}, node_name(), Beacon.tag_id()) ::
          {:ok, trace()} | {:error, :no_trace}
  def trace(tables, start, tag) do
    with %__MODULE__{} = mv <- Map.get(tables, start),
         [stay | _] <- segments(mv, tag) do
      limit = tables |> Map.values() |> Enum.map(&length(segments(&1, tag))) |> Enum.sum()
      {back, entry} = walk_back(tables, tag, stay, [], limit)
      {fwd, status} = walk_forward(tables, tag, stay, [], limit)
      path = back ++ [{start, stay} | Enum.reverse(fwd)]
      {:ok, %{path: merge(path), entry: entry, status: status}}
    else
      _ -> {:error, :no_trace}
    end
  end

  defp walk_back(_tables, _tag, _stay, acc, 0), do: {acc, :broken}

  defp walk_back(tables, tag, stay, acc, limit) do
    case stay.from do
      :infinity ->
        {acc, :infinity}

      :pending ->
        {acc, :pending}

      node ->
        with %__MODULE__{} = mv <- Map.get(tables, node),
             %{} = prev <- departure(mv, tag, stay.from_left_at) do
          walk_back(tables, tag, prev, [{node, prev} | acc], limit - 1)
        else
          _ -> {acc, :broken}
        end
    end
  end

  defp walk_forward(_tables, _tag, _stay, acc, 0), do: {acc, :broken}

  defp walk_forward(tables, tag, stay, acc, limit) do
    case stay.to do
      nil ->
        {acc, :present}

      :pending ->
        {acc, :in_transit}

      :infinity ->
        {acc, :exited}

      node ->
        with %__MODULE__{} = mv <- Map.get(tables, node),
             %{} = next <- arrival(mv, tag, stay.to_arrived_at) do
          walk_forward(tables, tag, next, [{node, next} | acc], limit - 1)
        else
          _ -> {acc, :broken}
        end
    end
  end

  defp merge(path) do
    path
    |> Enum.map(fn {node, s} -> %{node: node, arrived_at: s.arrived_at, left_at: s.left_at} end)
    |> Enum.chunk_while(
      nil,
      fn
        step, nil -> {:cont, step}
        %{node: n} = step, %{node: n} = cur -> {:cont, %{cur | left_at: step.left_at}}
        step, cur -> {:cont, cur, step}
      end,
      fn
        nil -> {:cont, nil}
        cur -> {:cont, cur, nil}
      end
    )
  end
end
