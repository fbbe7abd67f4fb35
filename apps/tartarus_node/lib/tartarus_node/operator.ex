defmodule TartarusNode.Operator do
  @moduledoc """
  The operator's way into a node that runs TLS distribution, with nothing but the release:
  `bin/tartarus remote`, `rpc`, `stop`, `restart` and `pid`.

  Under TLS a node admits a peer only under a name the peer's certificate names
  (`:tartarus_tls_dist`), so the release's usual `rpc-<random>-<node>` name, dialling with
  the node's own certificate, is refused (the node logs `disallowed node rpc-...`). Instead
  these commands run under the name of an operator's certificate, issued by the same CA:

      mix tartarus.gen.certs --out certs --nodes tartarus@pi1.local,operator --hosts pi1.local

  `operator.pem` and `operator.key` go beside the node's `ca.pem` (the certificate's name is
  `tls: [operator: "operator"]` in the node's file, the default). The command then runs as
  the hidden node `operator@<the node's host>` (the name that certificate names on that
  host), over TLS with the operator's option file (written into `TARTARUS_TMP`), the node's
  flags otherwise.

  Before anything is dialled, `check/2` refuses with one line naming the cause when the
  operator's certificate or key is missing or unreadable, was not issued by the node's CA
  (or has expired), does not name the operator's node name, or when that name is in use
  (another operator command is attached: one at a time per certificate).
  """

  alias TartarusNode.Config

  @commands ~w(remote rpc stop restart pid)

  @typedoc "The operator's node name and option file."
  @type t :: %{name: String.t(), optfile: Path.t(), cert: Path.t(), key: Path.t()}

  @doc """
  Whether `command` (the release's `RELEASE_COMMAND`) is one that only dials the running node.

      iex> TartarusNode.Operator.command?("remote")
      true
      iex> TartarusNode.Operator.command?("start")
      false
  """
  @spec command?(String.t() | nil) :: boolean()
  def command?(command), do: command in @commands

  @doc """
  The operator's node name for configuration `c`: the certificate's name at the node's host.

      iex> {:ok, c} = TartarusNode.Config.check(node: "tartarus@pi1.local", cookie: "c")
      iex> TartarusNode.Operator.name(c, "operator")
      "operator@pi1.local"
  """
  @spec name(Config.t(), String.t()) :: String.t()
  def name(c, operator), do: "#{operator}@#{c.node |> String.split("@") |> List.last()}"

  @doc """
  Checks the operator's certificate for the TLS node of `c` and writes the operator's option
  file into `tmp`: `{:ok, t()}`, or `{:error, line}` naming the cause.
  """
  @spec check(Config.t(), Path.t()) :: {:ok, t()} | {:error, String.t()}
  def check(%{tls: tls} = c, tmp) do
    dir = Path.dirname(tls.ca)
    cert = Path.join(dir, "#{tls.operator}.pem")
    key = Path.join(dir, "#{tls.operator}.key")
    name = name(c, tls.operator)
    command = System.get_env("RELEASE_COMMAND") || "remote"
    refuse = fn why -> {:error, "tartarus: #{command}: refused before connecting: #{why}"} end

    with {:ok, cert_pem} <- read(cert, c, refuse),
         {:ok, _key_pem} <- read(key, c, refuse),
         {:ok, ca_pem} <- read(tls.ca, c, refuse),
         :ok <- issued_by(cert_pem, cert, ca_pem, tls.ca, refuse),
         :ok <- names(cert_pem, cert, name, refuse),
         :ok <- free(name, refuse) do
      optfile = Path.join(tmp, "#{name}.ssl_dist.conf")
      terms = Config.optfile_terms(%{tls: %{tls | cert: cert, key: key}})

      case File.mkdir_p(tmp) do
        :ok ->
          text = :io_lib.format(~c"~tp.~n", [terms])
          File.write!(optfile, ["%% ssl_dist options for #{name}; written by the release.\n", text])
          {:ok, %{name: name, optfile: optfile, cert: cert, key: key}}

        {:error, reason} ->
          refuse.(
            "cannot write #{tmp} (#{:file.format_error(reason)}): set RELEASE_TMP to a directory of yours"
          )
      end
    end
  end

  defp read(file, c, refuse) do
    case File.read(file) do
      {:ok, text} ->
        {:ok, text}

      {:error, :enoent} ->
        refuse.(
          "no operator certificate #{file}: this node runs TLS distribution, and its " <>
            "operator's commands need a certificate of their own from the node's CA " <>
            "(mix tartarus.gen.certs --nodes #{c.tls.operator} --hosts #{host(c)}, " <>
            "then #{c.tls.operator}.pem and .key beside ca.pem)"
        )

      {:error, reason} ->
        refuse.("cannot read #{file} (#{:file.format_error(reason)})")
    end
  end

  defp host(c), do: c.node |> String.split("@") |> List.last()

  defp issued_by(cert_pem, cert, ca_pem, ca, refuse) do
    with [{:Certificate, der, _} | _] <- :public_key.pem_decode(cert_pem),
         [{:Certificate, ca_der, _} | _] <- :public_key.pem_decode(ca_pem) do
      case :public_key.pkix_path_validation(ca_der, [der], []) do
        {:ok, _} ->
          :ok

        {:error, {:bad_cert, :cert_expired}} ->
          refuse.("#{cert} has expired")

        {:error, {:bad_cert, reason}} ->
          refuse.("#{cert} was not issued by this node's CA #{ca} (#{inspect(reason)})")
      end
    else
      _ -> refuse.("#{cert} or #{ca} holds no PEM certificate")
    end
  end

  defp names(cert_pem, cert, name, refuse) do
    [{:Certificate, der, _} | _] = :public_key.pem_decode(cert_pem)
    names = :tartarus_tls_dist.cert_names(:public_key.pkix_decode_cert(der, :otp))

    if String.to_charlist(name) in names,
      do: :ok,
      else:
        refuse.(
          "#{cert} names #{Enum.join(names, ", ")}, not #{name} (issue it with --hosts #{name |> String.split("@") |> List.last()})"
        )
  end

  # The operator's name at this machine's epmd: taken while another operator command runs.
  defp free(name, refuse) do
    [alive, _host] = String.split(name, "@")

    case :erl_epmd.names() do
      {:ok, names} ->
        if Enum.any?(names, fn {n, _port} -> List.to_string(n) == alive end),
          do:
            refuse.(
              "#{name} is in use: another operator command is attached (one at a time per operator certificate)"
            ),
          else: :ok

      {:error, _} ->
        :ok
    end
  end

  @doc """
  The shell assignments `env.sh` evaluates for an operator's command: the node's name,
  cookie and distribution, `TARTARUS_OPERATOR` (the operator's node name, which `env.sh`
  runs the command under) and the client flags with the operator's option file.
  """
  @spec shell(Config.t(), t(), String.t()) :: String.t()
  def shell(c, op, _command) do
    Config.shell_assignments(
      RELEASE_DISTRIBUTION: Atom.to_string(c.distribution),
      RELEASE_NODE: c.node,
      RELEASE_COOKIE: c.cookie,
      TARTARUS_OPERATOR: op.name,
      TARTARUS_ERL_FLAGS: Enum.join(Config.erl_flags(c, op.optfile, :client), " ")
    )
  end
end
