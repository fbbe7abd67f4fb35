defmodule Mix.Tasks.Tartarus.Node do
  @shortdoc "Starts a named node with a Tartarus host, for iex --remsh"

  @schema [
    name: [type: :string, required: true, doc: "the node's short name; the node is `NAME@<hostname>`"],
    host: [type: :string, default: "main", doc: "the host's name"],
    neighbours: [type: :string, doc: "comma-separated `host:node` addresses to link to"],
    cookie: [type: :string, default: "tartarus", doc: "the distribution cookie"],
    sensor: [
      type: :string,
      doc: "attach a simulated sensor plugin under this name (a sine-like script)"
    ],
    dashboard: [
      type: :non_neg_integer,
      doc: "serve the web dashboard (`TartarusTools.Dashboard`) on this port"
    ],
    dashboard_bind: [
      type: :string,
      default: "127.0.0.1",
      doc: "the address the dashboard listens on"
    ],
    dashboard_token_file: [
      type: :string,
      doc: "read the dashboard's action token from this file (default: a random one, printed)"
    ]
  ]
  @moduledoc """
  Starts this VM as a named BEAM node running one Tartarus host, links it to neighbour
  hosts on other nodes, and keeps running until interrupted.

      ELIXIR_ERL_OPTIONS="-connect_all false" mix tartarus.node --name n1 --host h1
      ELIXIR_ERL_OPTIONS="-connect_all false" mix tartarus.node --name n2 --host h2 --neighbours h1:n1@$(hostname -s)

  Options (flags are the keys with dashes):

  #{Tartarus.Options.docs(@schema)}

  The host itself starts with `Tartarus.start_host/2`'s defaults (see its documentation),
  among them the admission policy's finite limits.

  Then attach a shell and drive it with the `Tartarus` API:

      iex --sname me --cookie tartarus --remsh n1@<hostname>
      iex> Tartarus.status(:h1)

  `-connect_all false` keeps nodes from forming a full mesh (they connect only to the nodes
  their hosts talk to); it must be given to the VM at boot, hence `ELIXIR_ERL_OPTIONS`.
  """
  use TartarusTools.CLI

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.options!(argv, @schema, "tartarus.node")
    neighbours = parse_neighbours(opts[:neighbours])
    name = opts[:name]
    _ = System.cmd("epmd", ["-daemon"])

    case Node.start(String.to_atom(name), :shortnames) do
      {:ok, _} ->
        :ok

      {:error, reason} ->
        Mix.raise("mix tartarus.node: cannot start node #{name}: #{inspect(reason)}")
    end

    Node.set_cookie(String.to_atom(opts[:cookie]))
    Mix.Task.run("app.start")

    unless :init.get_argument(:connect_all) == {:ok, [[~c"false"]]} do
      Mix.shell().info("note: started without -connect_all false; nodes may form a full mesh")
    end

    host_name = String.to_atom(opts[:host])

    plugins =
      case opts[:sensor] do
        nil ->
          []

        s ->
          [
            {String.to_atom(s),
             {Tartarus.Plugin.SimSensor,
              signal: Enum.map(0..59, &(20 + :math.sin(&1 / 10) * 5)), unit: "°C"}}
          ]
      end

    case Tartarus.start_host(host_name, neighbours: neighbours, plugins: plugins) do
      {:ok, host} ->
        Mix.shell().info(
          "host #{inspect(host)} running; neighbours: #{inspect(Tartarus.neighbours(host))}"
        )

        Mix.shell().info(
          "attach with: iex --sname me --cookie #{Node.get_cookie()} --remsh #{node()}"
        )

        if opts[:dashboard], do: start_dashboard(opts)

        Process.sleep(:infinity)

      {:error, reason} ->
        Mix.raise("mix tartarus.node: cannot start host: #{inspect(reason)}")
    end
  end

  defp start_dashboard(opts) do
    bind =
      case :inet.parse_address(String.to_charlist(opts[:dashboard_bind])) do
        {:ok, ip} -> ip
        _ -> Mix.raise("mix tartarus.node: --dashboard-bind expects an IP address, got: #{opts[:dashboard_bind]}")
      end

    dash_opts =
      [port: opts[:dashboard], bind: bind] ++
        if(opts[:dashboard_token_file], do: [token_file: opts[:dashboard_token_file]], else: [])

    case TartarusTools.Dashboard.start(dash_opts) do
      {:ok, dash} -> Mix.shell().info(TartarusTools.Dashboard.banner(dash))
      {:error, reason} -> Mix.raise("mix tartarus.node: cannot start the dashboard: #{inspect(reason)}")
    end
  end

  defp parse_neighbours(nil), do: []

  defp parse_neighbours(list) do
    list
    |> String.split(",", trim: true)
    |> Enum.map(fn item ->
      case String.split(item, ":", parts: 2) do
        [h, n] -> {String.to_atom(h), String.to_atom(n)}
        _ -> Mix.raise("mix tartarus.node: --neighbours expects host:node items, got: #{item}")
      end
    end)
  end
end
