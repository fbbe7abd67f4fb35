defmodule TartarusImmune.Cache do
  @moduledoc """
  A memo of `domain.score/2` per `{domain, solution, ref, seed}` in a public ETS table of
  this BEAM node (`:tartarus_immune_costs`), for emulations that run many hosts in one VM:
  the score is a pure function of the instance, so the memo changes no result, only the
  time. Where the table does not exist (a peer node), the score is computed each time.
  """

  @table :tartarus_immune_costs

  @doc "Creates the table on this node if it does not exist (owned by the caller)."
  @spec ensure() :: :ok
  def ensure do
    if :ets.whereis(@table) == :undefined do
      :ets.new(@table, [:named_table, :public, :set, read_concurrency: true])
    end

    :ok
  rescue
    ArgumentError -> :ok
  end

  @doc "The cost of `sol` on instance `ref` (materialized as `inst`), memoized."
  @spec score(module(), module(), term(), integer(), term()) :: number()
  def score(domain, sol, ref, seed, inst) do
    key = {domain, sol, ref, seed}

    case lookup(key) do
      {:ok, c} ->
        c

      :none ->
        c = domain.score(sol, inst)
        store(key, c)
        c
    end
  end

  defp lookup(key) do
    case :ets.lookup(@table, key) do
      [{_, c}] -> {:ok, c}
      [] -> :none
    end
  rescue
    ArgumentError -> :none
  end

  defp store(key, c) do
    :ets.insert(@table, {key, c})
  rescue
    ArgumentError -> true
  end
end
