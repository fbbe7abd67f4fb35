defmodule TartarusLats.Cloud do
  @moduledoc """
  The cloud server of the thesis's comparison (§3.4.3-3.4.5), as a static
  agent named `"lats-cloud"` on a host of its own (by default `:cloud`).

  It counts every connection a node (or an agent on a node) makes to it,
  with the bytes carried, the world second and the tags concerned, split by
  design:

    * `:centralized` (Scenario 1) - `{:upload, %{node, time, records,
      vectors}}` posted by the database agents (`centralized: true`) with
      every new record and every new or changed stay (only those: a stay is known by
      its arrival time, and the cloud merges it into its mirror). The cloud keeps a mirror of every
      node's motion vectors and answers queries centrally from it
      (`{:query, type, start, tag}` requests), with the same decision
      functions as the query agents (`TartarusLats.Query`).
    * `:agents` (Scenario 2) - `{:answer, %{query, type, tag, time, node,
      answer}}` posted by a query agent, once, from the node where it found
      the data that answers it.

  A connection is one post; its bytes are `:erlang.external_size/1` of the
  message.

  Requests: `{:sync, n}` is answered (`:ok`) once the cloud has taken `n`
  uploads in all (the driver's barrier, see `TartarusLats.DatabaseAgent`);
  `:stats` returns `%{connections: %{design => n}, bytes: %{design
  => n}, log: [%{design, time, tags, bytes, query_type}]}` (log oldest first;
  `query_type` is the query's type for an agent's contact, nil for an upload);
  `{:query, :where_is | :where_am_i | :trace, start_node, tag}` returns the
  centralized answer.
  """
  use Tartarus.Agent

  alias Tartarus.Agent, as: A
  alias TartarusLats.{MotionVectors, Query}

  @name "lats-cloud"

  @doc "The name of the cloud agent."
  @spec agent_name() :: String.t()
  def agent_name, do: @name

  @doc """
  Starts the cloud: a host `name` (default `:cloud`) with the cloud agent.
  Returns `{:ok, host}`.
  """
  @spec start(Tartarus.host_name()) :: {:ok, Tartarus.host()} | {:error, term()}
  def start(name \\ :cloud) do
    with {:ok, host} <- Tartarus.start_host(name),
         {:ok, _} <- Tartarus.create_static_agent(host, __MODULE__, nil, name: @name) do
      {:ok, host}
    end
  end

  @doc "The cloud's counters (see the moduledoc)."
  @spec stats(Tartarus.host_ref()) :: map()
  def stats(host) do
    {:ok, stats} = Tartarus.request({@name, host}, :stats, 30_000)
    stats
  end

  @doc "Asks the cloud to answer a query centrally (Scenario 1)."
  @spec query(Tartarus.host_ref(), atom(), term(), TartarusLats.Beacon.tag_id()) :: term()
  def query(host, type, start, tag) do
    {:ok, answer} = Tartarus.request({@name, host}, {:query, type, start, tag}, 30_000)
    answer
  end

  @impl true
  def init(_args) do
    {:stay,
     %{
       tables: %{},
       connections: %{centralized: 0, agents: 0},
       bytes: %{centralized: 0, agents: 0},
       log: [],
       waiting: []
     }}
  end

  @impl true
  def handle_message({:upload, %{node: node, time: t} = up} = msg, _from, s) do
    tables =
      Enum.reduce(up.vectors, s.tables, fn {tag, segs}, tables ->
        Map.update(tables, node, %{tag => merge([], segs)}, fn table ->
          Map.update(table, tag, merge([], segs), &merge(&1, segs))
        end)
      end)

    tags =
      (Enum.map(up.records, &{&1.uuid, &1.major, &1.minor}) ++ Enum.map(up.vectors, &elem(&1, 0)))
      |> Enum.uniq()

    {:stay, %{s | tables: tables} |> count(:centralized, t, tags, msg) |> release()}
  end

  def handle_message({:sync, n}, from, s),
    do: {:stay, release(%{s | waiting: [{n, from} | s.waiting]})}

  def handle_message({:answer, %{time: t, tag: tag} = a} = msg, _from, s),
    do: {:stay, count(s, :agents, t, [tag], msg, Map.get(a, :type))}

  def handle_message(:stats, from, s) do
    A.reply(from, %{connections: s.connections, bytes: s.bytes, log: Enum.reverse(s.log)})
    {:stay, s}
  end

  def handle_message({:query, type, start, tag}, from, s) do
    tables = Map.new(s.tables, fn {n, tags} -> {n, %MotionVectors{node: n, tags: tags}} end)

    answer =
      case type do
        :trace -> Query.trace(tables, start, tag)
        _ -> Query.where_is(tables, start, tag)
      end

    A.reply(from, answer)
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  defp release(s) do
    {done, waiting} = Enum.split_with(s.waiting, fn {n, _} -> s.connections.centralized >= n end)

    Enum.each(done, fn {_, from} -> A.reply(from, :ok) end)
    %{s | waiting: waiting}
  end

  defp count(s, design, t, tags, msg, query_type \\ nil) do
    bytes = :erlang.external_size(msg)

    %{
      s
      | connections: Map.update!(s.connections, design, &(&1 + 1)),
        bytes: Map.update!(s.bytes, design, &(&1 + bytes)),
        log: [
          %{design: design, time: t, tags: tags, bytes: bytes, query_type: query_type} | s.log
        ]
    }
  end

  # An upload carries only the stays that are new or changed (known by their arrival time);
  # the mirror keeps a node's list as the node does, newest first.
  defp merge(list, changed) do
    changed
    |> Enum.reduce(Map.new(list, &{&1.arrived_at, &1}), &Map.put(&2, &1.arrived_at, &1))
    |> Map.values()
    |> Enum.sort_by(& &1.arrived_at, :desc)
  end
end
