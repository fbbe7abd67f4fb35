defmodule Mix.Tasks.Tartarus.Gen.Certs do
  @shortdoc "Generates a CA and per-node certificates for TLS distribution"

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
  certificates: a node may connect only under a name its certificate names, so give `--nodes`
  the names the nodes will run under (`a` for `a@<any listed host>`, or `a@host`).

  ## Options

    * `--out DIR` - output directory, default `certs`;
    * `--nodes a,b,c` - node names (`name` or `name@host`), required;
    * `--hosts h1,h2` - host names or IP addresses the node certificates are valid for, default
      this machine's host name and `localhost`; TLS distribution checks the host part of the
      node name it dials against them;
    * `--days N` - validity in days, default 365.

  See `Tartarus.Security.Certs` for what the certificates contain and prove.
  """

  use Mix.Task

  alias Tartarus.Security.Certs

  @switches [out: :string, nodes: :string, hosts: :string, days: :integer]

  @impl Mix.Task
  def run(argv) do
    case OptionParser.parse(argv, strict: @switches) do
      {opts, [], []} ->
        generate(opts)

      {_opts, [extra | _], _} ->
        Mix.raise("unexpected argument #{inspect(extra)}; usage: #{usage()}")

      {_opts, _args, [{switch, nil} | _]} ->
        Mix.raise("unknown option #{switch}; usage: #{usage()}")

      {_opts, _args, [{switch, value} | _]} ->
        Mix.raise(
          "invalid value for #{switch}: expected #{expected(switch)}, got: #{inspect(value)}"
        )
    end
  end

  defp generate(opts) do
    out = Keyword.get(opts, :out, "certs")
    nodes = split(Keyword.get(opts, :nodes, ""))

    if nodes == [] do
      Mix.raise(
        "missing --nodes: expected a comma-separated list of node names; usage: #{usage()}"
      )
    end

    cert_opts =
      [nodes: nodes, days: Keyword.get(opts, :days, 365)] ++
        if hosts = opts[:hosts], do: [hosts: split(hosts)], else: []

    case Certs.generate(out, cert_opts) do
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
        Mix.raise(message)
    end
  end

  defp split(list), do: list |> String.split(",", trim: true) |> Enum.map(&String.trim/1)

  defp expected("--days"), do: "a positive integer"
  defp expected(_), do: "a value"

  defp usage,
    do: "mix tartarus.gen.certs --nodes a,b[,...] [--out DIR] [--hosts h1,h2] [--days N]"
end
