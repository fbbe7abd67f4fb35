defmodule Mix.Tasks.Tartarus.Gen.Certs do
  @shortdoc "Generates a CA and per-node certificates for TLS distribution"

  @schema [
    out: [type: :string, default: "certs", doc: "output directory"],
    nodes: [
      type: :string,
      required: true,
      doc: "comma-separated node names (`name` or `name@host`)"
    ],
    hosts: [
      type: :string,
      doc:
        "comma-separated host names or IP addresses the node certificates are valid for " <>
          "(default: this machine's host name and `localhost`); TLS distribution checks the " <>
          "host part of the node name it dials against them"
    ],
    days: [
      type: :pos_integer,
      doc: "validity in days (when not given, `Tartarus.Security.Certs.generate/2`'s default)"
    ],
    json: [
      type: :boolean,
      default: false,
      doc:
        "print one JSON object (`ca`, `ca_created`, `nodes`: name => files) instead of the lines"
    ]
  ]

  @moduledoc """
  Generates a certificate authority and one certificate per node for TLS distribution with
  mutual authentication, in pure OTP (no `openssl` needed).

      mix tartarus.gen.certs --out certs --nodes a,b,c --days 365

  writes into `certs/`:

    * `ca.pem`, `ca.key` - the CA (reused if already there, so nodes can be added later);
    * `<node>.pem`, `<node>.key` - each node's certificate and key (keys are mode 0600);
    * `<node>.ssl_dist.conf` - each node's `-ssl_dist_optfile`.

  Then start a node with the flags from `Tartarus.Security.TLSDist.erl_flags/2`:

      elixir --sname a --erl "-proto_dist tartarus_tls -ssl_dist_optfile certs/a.ssl_dist.conf -pa <tartarus ebin>" ...

  `tartarus_tls` (`:tartarus_tls_dist`) is OTP's `inet_tls` with node names bound to
  certificates: a node may connect, and be dialled, only under a name its certificate names,
  so give `--nodes` the names the nodes will run under (`a` for `a@<any listed host>`, or
  `a@host`).

  ## Options

  Flags are the keys with dashes; `--help` prints this documentation.

  #{TartarusTools.CLI.flag_docs(@schema)}

  See `Tartarus.Security.Certs` for what the certificates contain and prove.
  """

  use TartarusTools.CLI

  alias Tartarus.Security.Certs

  @impl Mix.Task
  def run(argv), do: argv |> TartarusTools.CLI.options!(@schema, "tartarus.gen.certs") |> generate()

  defp generate(opts) do
    out = opts[:out]
    nodes = split(opts[:nodes])

    if nodes == [] do
      Mix.raise("mix tartarus.gen.certs: --nodes must name at least one node, got: \"\"")
    end

    cert_opts =
      [nodes: nodes] ++
        Keyword.take(opts, [:days]) ++
        if hosts = opts[:hosts], do: [hosts: split(hosts)], else: []

    json? = opts[:json]

    case Certs.generate(out, cert_opts) do
      {:ok, %{ca: ca, ca_created?: created?}} when json? ->
        files = fn node ->
          for ext <- ~w(pem key ssl_dist.conf), do: Path.join(Path.expand(out), "#{node}.#{ext}")
        end

        TartarusTools.CLI.report(
          %{ca: ca, ca_created: created?, nodes: Map.new(nodes, &{&1, files.(&1)})},
          json: true
        )

      {:ok, %{ca: ca, ca_created?: created?}} ->
        Mix.shell().info(
          "#{if created?, do: "created", else: "reused"} CA #{ca}\n" <>
            Enum.map_join(
              nodes,
              "\n",
              &"issued #{Path.join(Path.expand(out), &1)}.{pem,key,ssl_dist.conf}"
            )
        )

      {:error, message} ->
        TartarusTools.CLI.error!("tartarus.gen.certs", message)
    end
  end

  defp split(list), do: list |> String.split(",", trim: true) |> Enum.map(&String.trim/1)
end
