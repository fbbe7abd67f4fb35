defmodule TartarusTools.Demo do
  @moduledoc """
  Sections of `mix tartarus.demo`.

  Each application adds its sections by naming modules that implement this behaviour in
  its application environment under `:tartarus_demo` (in its `mix.exs`), so the platform's
  demo task runs them without knowing the applications:

      def application do
        [mod: ..., env: [tartarus_demo: [MyApp.Demo]]]
      end

  Sections run in the order: the platform's first, then the applications' in alphabetical
  order of application name.
  """

  @doc "A one-line title of the section."
  @callback title() :: String.t()

  @doc "Runs the section, printing what happens with `say/1`. Options: `:seed`, `:out`."
  @callback run(keyword()) :: :ok | {:error, term()}

  @doc "The demo sections of all loaded applications, in running order."
  @spec sections() :: [module()]
  def sections do
    apps =
      Application.loaded_applications()
      |> Enum.map(&elem(&1, 0))
      |> Enum.sort()

    own = Application.get_env(:tartarus_tools, :tartarus_demo, [])

    others =
      Enum.flat_map(apps -- [:tartarus_tools], &Application.get_env(&1, :tartarus_demo, []))
    own ++ others
  end

  @doc "Prints a line of the demo's narrative."
  @spec say(iodata()) :: :ok
  def say(line), do: IO.puts(["  ", line])
end

defmodule TartarusTools.Demo.Platform do
  @moduledoc false
  # The platform part of the demo: an agent whose module exists only on the first of three
  # real BEAM nodes travels around them, is cloned, and gets a message after it moved.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  @source """
  defmodule DemoTraveller do
    use Tartarus.Agent

    def init(_), do: {:stay, %{trail: []}}

    def handle_arrival(ctx, s) do
      {:stay, %{s | trail: s.trail ++ [ctx.host]}}
    end

    def handle_message({:go, dest}, _from, s), do: {:move, dest, s}

    def handle_message(:report, from, s) do
      Tartarus.Agent.reply(from, %{host: Tartarus.Agent.host(), node: node(), trail: s.trail,
        hops: Tartarus.Agent.hops(), clone_of: nil, note: Map.get(s, :note)})
      {:stay, s}
    end

    def handle_message({:note, text}, _from, s), do: {:stay, Map.put(s, :note, text)}
  end
  """

  @impl true
  def title, do: "Platform: an agent and its code cross three BEAM nodes"

  @impl true
  def run(_opts) do
    {:ok, peers} = TartarusTools.Peer.start_many("demo", 3)

    try do
      [a, b, c] = nodes = Enum.map(peers, &elem(&1, 1))
      hosts = for {n, h} <- Enum.zip(nodes, [:north, :centre, :south]), do: {h, n}
      for {h, n} <- hosts, do: {:ok, _} = :erpc.call(n, Tartarus, :start_host, [h])
      [north, centre, south] = hosts
      :ok = Tartarus.connect(north, centre)
      :ok = Tartarus.connect(centre, south)
      say("started 3 BEAM nodes: #{Enum.join(nodes, ", ")}; hosts north -- centre -- south")

      {:ok, [mod]} = :erpc.call(a, Tartarus, :compile_string, [@source])

      say(
        "compiled #{inspect(mod)} on #{a} only; loaded on #{b}? #{loaded?(b, mod)}; on #{c}? #{loaded?(c, mod)}"
      )

      {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:north, mod, nil])
      say("created agent #{id} on north")

      :ok = Tartarus.move({id, north}, centre)
      :ok = Tartarus.move({id, north}, south)
      {:ok, r} = Tartarus.request({id, north}, :report)

      say(
        "moved north -> centre -> south; asked through north (forwarding pointers): now on #{inspect(r.host)}, #{r.hops} hops, trail #{inspect(r.trail)}"
      )

      say("code went along: loaded on #{b}? #{loaded?(b, mod)}; on #{c}? #{loaded?(c, mod)}")

      shipped = for n <- nodes, do: {n, :erpc.call(n, Tartarus.Events, :totals, []).code_bytes}
      say("code bytes sent per node: #{inspect(shipped)} (each link carried the module once)")

      {:ok, clone} = Tartarus.clone({id, south}, centre)

      say(
        "cloned it to centre: clone #{clone}; agents on south: #{length(Tartarus.agents(south))}, on centre: #{length(Tartarus.agents(centre))}"
      )

      :ok = Tartarus.move({id, south}, north)
      :ok = Tartarus.post({id, south}, {:note, "posted via south after it left"})
      {:ok, r} = Tartarus.request({id, centre}, :report)

      say(
        "moved back to north, then posted to it at south: it got #{inspect(r.note)} on #{inspect(r.host)}"
      )

      hop = Tartarus.hop_stats(north)

      say(
        "hop times into north: #{hop.count} arrivals, median #{hop.median_us} µs (a first hop between two nodes also sets up their connection)"
      )

      :ok
    after
      stop_peers(peers)
    end
  end

  defp stop_peers(peers), do: Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end)

  defp loaded?(node, mod), do: :erpc.call(node, :code, :is_loaded, [mod]) != false
end
