defmodule Tartarus.MigrationPropertyTest do
  # For random sequences of creates, moves, clones and kills over a few hosts, the set of
  # live agent ids across all hosts equals the model's set: nothing lost, nothing duplicated.
  use ExUnit.Case, async: false

  @hosts [:prop_h1, :prop_h2, :prop_h3]

  defmodule Idle do
    use Tartarus.Agent
    def init(_), do: {:stay, nil}
  end

  defp command do
    host = :proper_types.oneof(@hosts)
    slot = :proper_types.integer(0, 7)

    :proper_types.frequency([
      {2, {:create, host}},
      {5, {:move, slot, host}},
      {2, {:clone, slot, host}},
      {1, {:kill, slot}}
    ])
  end

  defp run(commands) do
    for h <- @hosts, do: {:ok, _} = Tartarus.start_host(h)
    for a <- @hosts, b <- @hosts, a < b, do: :ok = Tartarus.connect(a, b)

    try do
      model = Enum.reduce(commands, [], fn cmd, ids -> step(cmd, ids) end)

      live = @hosts |> Enum.flat_map(&Tartarus.agents/1) |> Enum.map(& &1.id)
      Enum.sort(live) == Enum.sort(model) and length(Enum.uniq(live)) == length(live)
    after
      for h <- @hosts, do: Tartarus.stop_host(h)
    end
  end

  defp step({:create, host}, ids) do
    {:ok, id} = Tartarus.create_mobile_agent(host, Idle, nil)
    ids ++ [id]
  end

  defp step(_cmd, []), do: []

  defp step({:move, slot, host}, ids) do
    id = Enum.at(ids, rem(slot, length(ids)))
    {:ok, here} = Tartarus.whereis(id)
    :ok = Tartarus.move({id, here}, host)
    ids
  end

  defp step({:clone, slot, host}, ids) do
    id = Enum.at(ids, rem(slot, length(ids)))
    {:ok, clone} = Tartarus.clone(id, host)
    ids ++ [clone]
  end

  defp step({:kill, slot}, ids) do
    id = Enum.at(ids, rem(slot, length(ids)))
    :ok = Tartarus.kill(id)
    List.delete(ids, id)
  end

  test "live agents always equal the model's agents" do
    property =
      :proper.forall(:proper_types.list(command()), fn commands ->
        try do
          run(commands)
        rescue
          e ->
            IO.puts("exception in property: " <> Exception.format(:error, e, __STACKTRACE__))
            false
        end
      end)

    result = :proper.quickcheck(property, [:long_result, :quiet, {:numtests, 150}])

    assert result == true,
           "counterexample: " <> inspect(result, charlists: :as_lists, limit: :infinity)
  end
end
