defmodule Tartarus.ShippedCodeJournalTest do
  # Agents whose module is not on the node's code path (shipped, or compiled at run time)
  # are restored from a data directory: the module's binary is kept beside the journal,
  # content-addressed, and loaded before the agents start. A restore that cannot run an
  # agent (its code missing) keeps its records, so a later start with the module installed
  # restores it. Before, such agents were dropped and a {:forget} journaled for each: a
  # restart with the module installed still restored 0 of 60.
  use Tartarus.HostCase, async: false

  @n 60

  setup do
    dir = Path.join(System.tmp_dir!(), "shipped_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    mod = :"Elixir.Tartarus.ShippedCodeJournalTest.Agent#{System.unique_integer([:positive])}"
    on_exit(fn -> forget_module(mod) end)
    %{dir: dir, mod: mod}
  end

  defp install(mod) do
    {:ok, [^mod]} =
      Tartarus.compile_string("""
      defmodule #{inspect(mod)} do
        use Tartarus.Agent
        def init(n), do: {:stay, n}
        def handle_message(:state, from, n), do: (Tartarus.Agent.reply(from, n); {:stay, n})
      end
      """)

    :ok
  end

  # As on a node that never had the module: not loaded, not in the code cache.
  defp forget_module(mod) do
    :code.purge(mod)
    :code.delete(mod)
    :code.purge(mod)
    :ets.delete(Tartarus.CodeCache, mod)
    :ok
  end

  defp start!(name, dir) do
    {:ok, _} = Tartarus.start_host(name, data_dir: dir)
    on_exit(fn -> Tartarus.stop_host(name) end)
    name
  end

  defp listed(name), do: name |> Tartarus.agents() |> Enum.map(& &1.id) |> Enum.sort()

  test "agents of run-time code are restored on a node that lost the module (60 of 60)", ctx do
    :ok = install(ctx.mod)
    name = start!(unique_name(), ctx.dir)
    ids = Enum.sort(for i <- 1..@n, do: elem(Tartarus.create_agent(name, ctx.mod, i), 1))
    :ok = Tartarus.stop_host(name)
    # The binary is kept once, by its md5.
    md5 = ctx.mod.module_info(:md5)
    assert File.ls!(Path.join(ctx.dir, "code")) == [Base.encode16(md5, case: :lower) <> ".beam"]

    :ok = forget_module(ctx.mod)
    refute Code.ensure_loaded?(ctx.mod)
    start!(name, ctx.dir)
    assert listed(name) == ids

    assert Enum.all?(Enum.with_index(ids), fn {id, _} ->
             match?({:ok, n} when is_integer(n), Tartarus.request({id, addr(name)}, :state))
           end)

    assert ctx.mod.module_info(:md5) == md5
  end

  test "a restore without the module keeps the agents' records: installed later, all 60 return",
       ctx do
    :ok = install(ctx.mod)
    name = start!(unique_name(), ctx.dir)
    ids = Enum.sort(for i <- 1..@n, do: elem(Tartarus.create_agent(name, ctx.mod, i), 1))
    :ok = Tartarus.stop_host(name)

    # The module missing everywhere (the kept binary lost too): nothing can run them.
    File.rm_rf!(Path.join(ctx.dir, "code"))
    :ok = forget_module(ctx.mod)
    start!(name, ctx.dir)
    assert listed(name) == []
    :ok = Tartarus.stop_host(name)

    :ok = install(ctx.mod)
    start!(name, ctx.dir)
    assert listed(name) == ids
  end

  test "the kept binary goes with the last agent that needs it", ctx do
    :ok = install(ctx.mod)
    name = start!(unique_name(), ctx.dir)
    {:ok, id} = Tartarus.create_agent(name, ctx.mod, 1)
    assert [_] = File.ls!(Path.join(ctx.dir, "code"))
    :ok = Tartarus.kill({id, addr(name)})
    :ok = Tartarus.stop_host(name)
    start!(name, ctx.dir)
    assert File.ls!(Path.join(ctx.dir, "code")) == []
  end
end
