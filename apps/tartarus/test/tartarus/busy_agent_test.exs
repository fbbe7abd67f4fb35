defmodule Tartarus.BusyAgentTest do
  # Reaching an agent that never stops moving (issue 9, item 7): posts follow it, are
  # handled exactly once and in each sender's order; with `durable: true` every
  # acknowledged message is in the agent's checkpointed state.
  use Tartarus.HostCase, async: false

  defmodule PingPong do
    @moduledoc false
    # Hops between two hosts at every arrival and after every message; records each
    # message {sender, seq} it handles (newest first) until told to stop.
    use Tartarus.Agent

    def init(s), do: {:stay, s}
    def handle_arrival(_ctx, s), do: next(s)
    def handle_message(:stop, _from, s), do: {:stay, %{s | stop: true}}

    def handle_message(:log, from, s) do
      Tartarus.Agent.reply(from, Enum.reverse(s.log))
      {:stay, s}
    end

    def handle_message({_sender, _seq} = m, _from, s), do: next(%{s | log: [m | s.log]})
    def handle_message(_other, _from, s), do: {:stay, s}

    defp next(%{stop: true} = s), do: {:stay, s}

    defp next(s) do
      here = Tartarus.Agent.host()
      {:move, if(here == s.a, do: s.b, else: s.a), s}
    end
  end

  defp run(opts, senders, per) do
    [a, b] = [host!(opts), host!(opts)]
    [a, b] = [addr(a), addr(b)]
    {:ok, id} = Tartarus.create_mobile_agent(a, PingPong, %{a: a, b: b, log: [], stop: false})

    results =
      1..senders
      |> Enum.map(fn s ->
        Task.async(fn -> for i <- 1..per, do: {i, Tartarus.post({id, a}, {s, i}, 30_000)} end)
      end)
      |> Task.await_many(120_000)

    :ok = Tartarus.post({id, a}, :stop, 30_000)
    {:ok, log} = Tartarus.request({id, a}, :log, 30_000)
    {id, results, log}
  end

  test "posts from 4 senders to an agent hopping at every arrival: each handled once, in order" do
    {_id, results, log} = run([], 4, 150)

    for r <- results, do: assert(Enum.all?(r, &match?({_, :ok}, &1)))
    assert length(log) == 600
    assert length(Enum.uniq(log)) == 600

    for s <- 1..4 do
      assert for({^s, i} <- log, do: i) == Enum.to_list(1..150)
    end
  end

  test "durable: every acknowledged post is in the checkpointed state, wherever the agent is" do
    dir = Path.join(System.tmp_dir!(), "busy_durable_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    {id, results, log} = run([data_dir: dir, durable: true], 2, 50)
    for r <- results, do: assert(Enum.all?(r, &match?({_, :ok}, &1)))
    assert Enum.sort(log) == for(s <- 1..2, i <- 1..50, do: {s, i})

    # The journal of the host the agent is on holds its state with every message.
    {:ok, host} = Tartarus.whereis(id)
    {:ok, info} = Tartarus.Host.local(host)
    {agents, _, _} = Tartarus.Host.Persistence.restored(replay(info.journal.path))
    [env] = for e <- agents, e.id == id, do: e
    assert Enum.sort(env.state.log) == Enum.sort(log)
  end

  # The journal as a restart would read it (without touching the file the host writes).
  defp replay(path) do
    {:ok, s, %{ranges: []}} = Tartarus.Host.Persistence.JournalFile.read(path)
    s
  end
end
