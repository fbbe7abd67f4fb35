defmodule TartarusTools.Bench.Durability do
  @moduledoc """
  The cost of durability, run by `mix tartarus.bench durability`: hops and posts per second
  between two hosts of this VM in three configurations, run one after the other with the
  same workload:

    * `memory`: no `:data_dir` (nothing written to disk);
    * `journal`: `data_dir:` (every arrival and hand-off decision journaled; a message is
      acknowledged when taken);
    * `durable`: `data_dir:` and `durable: true` (also every handled message checkpointed
      before its sender gets `:ok`).

  Hops: `:agents` agents (default 200) make `:hops` hops each (default 50) at once between
  the two hosts (`TartarusTools.Bench.run_batch/5`). Posts: `:senders` processes (default
  4) post `:messages` messages in all (default 20,000) to one agent, each waiting for its
  `:ok` before the next. Keys: `agents, hops, messages, senders, configs` (an object keyed
  by configuration, each with `hops_per_s, posts_per_s, us_per_post, journal_bytes`),
  `durable_posts_ratio`, `durable_hops_ratio` (durable / memory) and `journal_posts_ratio`,
  `journal_hops_ratio` (journal / memory).
  """

  alias Tartarus.Examples.Echo

  @doc """
  Runs the three configurations and returns their figures (see the moduledoc). Options:
  `:agents`, `:hops`, `:messages`, `:senders`.
  """
  @spec run(keyword()) :: map()
  def run(opts \\ []) do
    agents = Keyword.get(opts, :agents, 200)
    hops = Keyword.get(opts, :hops, 50)
    messages = Keyword.get(opts, :messages, 20_000)
    senders = Keyword.get(opts, :senders, 4)
    bouncer = TartarusTools.Bench.bouncer()

    configs =
      for config <- [:memory, :journal, :durable], into: %{} do
        {config, pass(config, bouncer, agents, hops, messages, senders)}
      end

    %{
      agents: agents,
      hops: hops,
      messages: messages,
      senders: senders,
      configs: configs,
      durable_posts_ratio: ratio(configs.durable.posts_per_s, configs.memory.posts_per_s),
      durable_hops_ratio: ratio(configs.durable.hops_per_s, configs.memory.hops_per_s),
      journal_posts_ratio: ratio(configs.journal.posts_per_s, configs.memory.posts_per_s),
      journal_hops_ratio: ratio(configs.journal.hops_per_s, configs.memory.hops_per_s)
    }
  end

  defp ratio(a, b), do: Float.round(a / max(b, 1.0e-9), 3)

  defp pass(config, bouncer, agents, hops, messages, senders) do
    tag = System.unique_integer([:positive])
    dir = Path.join(System.tmp_dir!(), "tartarus_bench_durability_#{tag}")

    opts =
      case config do
        :memory -> []
        :journal -> [data_dir: dir]
        :durable -> [data_dir: dir, durable: true]
      end

    {:ok, h1} = Tartarus.start_host(:"bdur1_#{tag}", opts)
    {:ok, h2} = Tartarus.start_host(:"bdur2_#{tag}", opts)

    try do
      hop_us = TartarusTools.Bench.run_batch(bouncer, h1, h2, List.duplicate(hops, agents), "")
      post_us = posts(h1, messages, senders)

      %{
        hops_per_s: Float.round(agents * hops * 1.0e6 / hop_us, 1),
        posts_per_s: Float.round(messages * 1.0e6 / post_us, 1),
        us_per_post: Float.round(post_us * senders / messages, 2),
        journal_bytes: journal_bytes(dir)
      }
    after
      Tartarus.stop_host(h1)
      Tartarus.stop_host(h2)
      File.rm_rf(dir)
    end
  end

  # Wall time in µs for `senders` processes to post `messages` messages in all to one agent.
  defp posts(host, messages, senders) do
    {:ok, id} = Tartarus.create_mobile_agent(host, Echo, 0)
    per = div(messages, senders)
    t0 = Tartarus.Clock.machine_time(:microsecond)

    1..senders
    |> Enum.map(fn s ->
      Task.async(fn ->
        for i <- 1..per, do: :ok = Tartarus.post({id, host}, {s, i})
      end)
    end)
    |> Enum.each(&Task.await(&1, :infinity))

    max(Tartarus.Clock.machine_time(:microsecond) - t0, 1)
  end

  defp journal_bytes(dir) do
    case File.ls(dir) do
      {:ok, files} -> Enum.sum(for f <- files, do: File.stat!(Path.join(dir, f)).size)
      _ -> 0
    end
  end
end
