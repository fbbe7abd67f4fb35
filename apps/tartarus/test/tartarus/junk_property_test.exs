defmodule Tartarus.JunkPropertyTest do
  # Random terms sent (as messages, casts and calls with short timeouts) to the processes of a
  # node with a few hosts and agents: afterwards every host is up and every agent answers.
  #
  # Targets: every registered process of the tartarus application (Process.registered/0
  # after the app started: our node-level services), every host's keeper and server, and
  # every agent process. Calls and casts go through GenServer; sends include hand-made
  # `{:"$gen_call", from, msg}` whose `from` is junk (which once crashed agents: gen_server
  # replies to whatever `from` a `{:reply, ...}` return names).
  use ExUnit.Case, async: false

  import Tartarus.HostCase, only: [unique_name: 1, addr: 1]

  alias Tartarus.Examples.Echo

  @hosts 3
  @agents_per_host 3
  # 200 cases of 100 terms: 20,000 terms per run.
  @cases 200
  @terms_per_case 100
  @call_timeout 20

  # -- generators -------------------------------------------------------------------

  # An operation: {kind, target slot, term}. Terms are PropEr's any() half of the time, else
  # messages shaped like the platform's own (right tags, junk fields), which reach deeper.
  defp op do
    kind = :proper_types.oneof([:send, :cast, :call])
    {kind, :proper_types.non_neg_integer(), :proper_types.oneof([:proper_types.any(), shaped()])}
  end

  defp shaped do
    any = :proper_types.any()
    slot = :proper_types.non_neg_integer()

    :proper_types.oneof([
      {:DOWN, {:ref}, :process, {:pid, slot}, any},
      {:EXIT, {:pid, slot}, any},
      :sweep,
      :hello,
      {:load, any},
      {:load, :proper_types.list({any, any, any})},
      {:watch, any, any},
      {:watch, any, {:pid, slot}},
      {:connect, any, any},
      {:connect, {any, :proper_types.atom()}, any},
      {:disconnect, any},
      {:create, any, any},
      {:kill, any},
      {:locate, any},
      :info,
      :restore,
      :monitored,
      :paused,
      {:"$tartarus_prepare", any, any, any, any, any, any, any, any},
      {:"$tartarus_decision?", any, any, {:pid, slot}},
      {:"$tartarus_decision", any, any},
      {:"$tartarus_commit", any, any},
      :"$tartarus_go",
      {:"$gen_call", any, any},
      {:"$gen_cast", any},
      {:tartarus_event, any}
    ])
  end

  # -- the node under test ------------------------------------------------------------

  defp start_node do
    for _ <- 1..@hosts do
      name = unique_name("junk")
      {:ok, _} = Tartarus.start_host(name)

      ids =
        for _ <- 1..@agents_per_host, do: elem(Tartarus.create_mobile_agent(name, Echo, :s), 1)

      {name, ids}
    end
  end

  defp stop_node(hosts), do: for({name, _} <- hosts, do: Tartarus.stop_host(name))

  # The registered processes of the tartarus application (in an umbrella test run, other
  # apps' processes are registered too).
  defp registered do
    Enum.filter(Process.registered(), fn name ->
      :application.get_application(Process.whereis(name)) == {:ok, :tartarus}
    end)
  end

  defp host_pid(name), do: elem(Tartarus.Host.Directory.whereis(addr(name)), 1)

  defp keepers(hosts) do
    for {name, _} <- hosts,
        [{sup, _}] = Registry.lookup(Tartarus.HostRegistry, {:host_sup, name}),
        {:keeper, pid, _, _} <- Supervisor.which_children(sup),
        do: pid
  end

  defp agent_pids(hosts) do
    for {_name, ids} <- hosts, id <- ids, {:ok, pid, _} = Tartarus.AgentTable.lookup(id), do: pid
  end

  defp targets(hosts) do
    registered() ++ keepers(hosts) ++ Enum.map(hosts, &host_pid(elem(&1, 0))) ++ agent_pids(hosts)
  end

  # -- running the property ----------------------------------------------------------------

  defp deliver({kind, slot, term}, targets, pids, sent) do
    target = Enum.at(targets, rem(slot, length(targets)))
    term = concrete(term, pids)
    :counters.add(sent, 1, 1)

    case kind do
      :send -> send(target, term)
      :cast -> GenServer.cast(target, term)
      :call -> quiet_call(fn -> GenServer.call(target, term, @call_timeout) end)
    end
  end

  defp quiet_call(fun) do
    fun.()
  catch
    :exit, _ -> :timeout_or_exit
  end

  # Placeholders become real refs and pids of the node under test.
  defp concrete({:ref}, _pids), do: make_ref()

  defp concrete({:pid, slot}, pids) when is_integer(slot),
    do: Enum.at(pids, rem(slot, length(pids)))

  defp concrete(t, pids) when is_tuple(t),
    do: t |> Tuple.to_list() |> concrete(pids) |> List.to_tuple()

  defp concrete([h | t], pids), do: [concrete(h, pids) | concrete(t, pids)]

  defp concrete(%{} = m, pids) when not is_struct(m),
    do: Map.new(m, fn {k, v} -> {k, concrete(v, pids)} end)

  defp concrete(t, _pids), do: t

  # Every host up (its server never restarted) and every agent answering where it was.
  defp healthy?(hosts, host_pids) do
    Enum.all?(hosts, fn {name, ids} ->
      up? =
        case Tartarus.Host.Directory.whereis(addr(name)) do
          {:ok, pid} -> pid == host_pids[name]
          _ -> false
        end

      up? and Enum.all?(ids, &(Tartarus.request({&1, name}, :where, 2_000) == {:ok, addr(name)}))
    end)
  end

  defp run_property(cases) do
    hosts = start_node()
    sent = :counters.new(1, [])

    try do
      host_pids = Map.new(hosts, fn {name, _} -> {name, host_pid(name)} end)
      targets = targets(hosts)

      property =
        :proper.forall(:proper_types.vector(@terms_per_case, op()), fn ops ->
          # (This PropEr cannot report exceptions raised in a property on OTP 25.)
          try do
            Enum.each(ops, &deliver(&1, targets, targets, sent))
            flush()
            healthy?(hosts, host_pids)
          rescue
            e ->
              IO.puts("exception in property: " <> Exception.format(:error, e, __STACKTRACE__))
              false
          end
        end)

      result =
        :proper.quickcheck(property, [:long_result, :quiet, {:numtests, cases}, {:max_size, 12}])

      {result, :counters.get(sent, 1), targets}
    after
      stop_node(hosts)
    end
  end

  # Late replies of calls that timed out.
  defp flush do
    receive do
      {ref, _} when is_reference(ref) -> flush()
      {[:alias | ref], _} when is_reference(ref) -> flush()
    after
      0 -> :ok
    end
  end

  @tag timeout: 300_000
  test "random terms to every service, keeper, host server and agent leave every host up and every agent answering" do
    dropped_before = Tartarus.Events.totals().dropped
    services = Map.new(registered(), &{&1, Process.whereis(&1)})
    {result, sent, targets} = run_property(@cases)

    assert result == true,
           "counterexample: " <> inspect(result, limit: 50, printable_limit: 200)

    assert sent >= 20_000
    # No service restarted either.
    assert Map.new(registered(), &{&1, Process.whereis(&1)}) == services
    assert length(targets) >= 3 + @hosts * (2 + @agents_per_host)
    # Most of them were dropped and counted (calls a target knows are answered).
    assert Tartarus.Events.totals().dropped - dropped_before > sent / 2
  end
end
