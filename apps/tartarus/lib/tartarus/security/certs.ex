defmodule Tartarus.Security.Certs do
  @moduledoc """
  A small certificate authority for TLS distribution, in pure OTP (`:public_key`, no `openssl`).

  `generate/2` makes (or reuses) a CA in a directory and issues one certificate per node, then
  writes the `ssl_dist` option file each node starts with (see `Tartarus.Security.TLSDist`).
  `mix tartarus.gen.certs` is a thin command line over it.

      Tartarus.Security.Certs.generate("certs", nodes: ["a", "b"], days: 365)
      #=> {:ok, %{ca: "certs/ca.pem", nodes: ["a", "b"]}}

  ## Files

    * `ca.pem`, `ca.key` - the CA certificate and its private key (mode 0600). Keep `ca.key`
      off the nodes: only `ca.pem` is needed to verify peers.
    * `<node>.pem`, `<node>.key` - a node's certificate (signed by the CA) and key (0600).
    * `<node>.ssl_dist.conf` - the node's `-ssl_dist_optfile`, with absolute paths to the files
      above (see `Tartarus.Security.TLSDist.optfile_terms/2`).

  ## The certificates

  Keys are ECDSA P-256, signatures ECDSA with SHA-256, serials random 64-bit. The CA has
  `basicConstraints CA:TRUE` and `keyUsage keyCertSign, cRLSign`. A node certificate has
  `CN=<node>`, a `subjectAltName` listing the host part of the node name (if any) and the
  `:hosts` (DNS names, or IP addresses as `iPAddress` entries and again as `dNSName`
  entries with their text, which OTP 25's hostname check compares a dialled address with),
  `keyUsage digitalSignature` and `extKeyUsage serverAuth, clientAuth`, since every node is
  both a TLS server and a client. Validity starts one hour in the past (clock skew) and lasts
  `:days`.

  `:hosts` defaults to this machine's host name and `"localhost"`, which suits nodes started
  with `--sname` on the machine that ran the generator. TLS distribution checks the host part of
  the node name it dials against these names, so give every host a node may run on.

  What a certificate proves: "our CA issued this certificate to the node named CN on these
  hosts". With `Tartarus.Security.TLSDist` (`-proto_dist tartarus_tls`) a node may connect,
  and be dialled, only under a name its certificate names (`<CN>@<host>` for the hosts above,
  or the CN itself when it is a whole node name), so issue each node's certificate under its
  node name. Protect the CA key accordingly.
  """

  require Record

  @hrl "public_key/include/public_key.hrl"
  Record.defrecordp(:tbs, :OTPTBSCertificate, Record.extract(:OTPTBSCertificate, from_lib: @hrl))

  # OIDs from public_key.hrl (macros are not visible to Elixir).
  @ecdsa_with_sha256 {1, 2, 840, 10045, 4, 3, 2}
  @id_ec_public_key {1, 2, 840, 10045, 2, 1}
  @secp256r1 {1, 2, 840, 10045, 3, 1, 7}
  @common_name {2, 5, 4, 3}
  @organization {2, 5, 4, 10}
  @basic_constraints {2, 5, 29, 19}
  @key_usage {2, 5, 29, 15}
  @ext_key_usage {2, 5, 29, 37}
  @subject_alt_name {2, 5, 29, 17}
  @subject_key_id {2, 5, 29, 14}
  @authority_key_id {2, 5, 29, 35}
  @server_auth {1, 3, 6, 1, 5, 5, 7, 3, 1}
  @client_auth {1, 3, 6, 1, 5, 5, 7, 3, 2}

  @typedoc "A DER-encoded certificate with its private key (an `ECPrivateKey` record)."
  @type issued :: %{cert: binary(), key: tuple()}

  @typedoc "Options for `generate/2` and the functions that issue certificates."
  @type option ::
          {:nodes, [String.t()]}
          | {:hosts, [String.t()]}
          | {:days, pos_integer()}
          | {:name, String.t()}

  @default_days 365

  @doc """
  Makes a self-signed CA valid for `:days` (default #{@default_days}), named `:name`
  (default `"Tartarus CA"`).
  """
  @spec generate_ca([option()]) :: issued()
  def generate_ca(opts \\ []) do
    key = new_key()
    name = subject(Keyword.get(opts, :name, "Tartarus CA"))
    ski = key_id(key)

    extensions = [
      ext(@basic_constraints, true, {:BasicConstraints, true, :asn1_NOVALUE}),
      ext(@key_usage, true, [:keyCertSign, :cRLSign]),
      ext(@subject_key_id, false, ski)
    ]

    %{cert: sign(name, name, key, key, days(opts), extensions), key: key}
  end

  @doc """
  Issues a certificate for `node_name` (e.g. `"a"` or `"a@host1"`) signed by `ca`, valid for
  `:days` (default #{@default_days}), for the host part of `node_name` and the `:hosts`
  (default: `default_hosts/0`).
  """
  @spec issue(issued(), String.t(), [option()]) :: issued()
  def issue(%{cert: ca_der, key: ca_key}, node_name, opts \\ []) do
    key = new_key()
    ca_subject = ca_der |> :public_key.pkix_decode_cert(:otp) |> subject_of()
    hosts = Enum.uniq(host_names(node_name) ++ Keyword.get_lazy(opts, :hosts, &default_hosts/0))

    extensions = [
      ext(@basic_constraints, false, {:BasicConstraints, false, :asn1_NOVALUE}),
      ext(@key_usage, true, [:digitalSignature]),
      ext(@ext_key_usage, false, [@server_auth, @client_auth]),
      ext(@subject_alt_name, false, Enum.flat_map(hosts, &alt_names/1)),
      ext(@subject_key_id, false, key_id(key)),
      ext(
        @authority_key_id,
        false,
        {:AuthorityKeyIdentifier, key_id(ca_key), :asn1_NOVALUE, :asn1_NOVALUE}
      )
    ]

    %{cert: sign(subject(node_name), ca_subject, key, ca_key, days(opts), extensions), key: key}
  end

  @doc """
  The hosts a node certificate names by default: this machine's host name, its short form
  (the name `--sname` nodes get) and `"localhost"`.
  """
  @spec default_hosts() :: [String.t()]
  def default_hosts do
    {:ok, hostname} = :inet.gethostname()
    hostname = List.to_string(hostname)
    [short | _] = String.split(hostname, ".")
    Enum.uniq([hostname, short, "localhost"])
  end

  @doc """
  Makes or reuses the CA in `dir` and issues a certificate and an `ssl_dist` option file for
  every node in `:nodes`.

  An existing `ca.pem` + `ca.key` pair in `dir` is reused, so nodes can be added later; pass
  another directory to start a new CA. Node certificates are always re-issued.
  """
  @spec generate(Path.t(), [option()]) ::
          {:ok, %{ca: Path.t(), ca_created?: boolean(), nodes: [String.t()]}}
          | {:error, String.t()}
  def generate(dir, opts \\ []) do
    nodes = Keyword.get(opts, :nodes, [])
    dir = Path.expand(dir)

    with :ok <- validate_nodes(nodes),
         :ok <- validate_hosts(Keyword.get(opts, :hosts, [])),
         :ok <- validate_days(Keyword.get(opts, :days, @default_days)),
         :ok <- mkdir(dir),
         {:ok, ca, created?} <- load_or_create_ca(dir, opts) do
      for node <- nodes do
        issued = issue(ca, node, opts)
        write_pair!(dir, node, issued)
        Tartarus.Security.TLSDist.write_optfile!(node, dir)
      end

      {:ok, %{ca: Path.join(dir, "ca.pem"), ca_created?: created?, nodes: nodes}}
    end
  end

  @doc """
  Reads the CA (`ca.pem` and `ca.key`) from `dir`.
  """
  @spec load_ca(Path.t()) :: {:ok, issued()} | {:error, String.t()}
  def load_ca(dir) do
    with {:ok, cert_pem} <- read(Path.join(dir, "ca.pem")),
         {:ok, key_pem} <- read(Path.join(dir, "ca.key")),
         [{:Certificate, der, :not_encrypted}] <- :public_key.pem_decode(cert_pem),
         [{:ECPrivateKey, _, :not_encrypted} = entry] <- :public_key.pem_decode(key_pem) do
      {:ok, %{cert: der, key: :public_key.pem_entry_decode(entry)}}
    else
      {:error, _} = error ->
        error

      _ ->
        {:error,
         "invalid CA in #{dir}: expected ca.pem with one certificate and ca.key with one " <>
           "EC private key"}
    end
  end

  @doc "Writes `<name>.pem` and `<name>.key` (mode 0600) into `dir`."
  @spec write_pair!(Path.t(), String.t(), issued()) :: :ok
  def write_pair!(dir, name, %{cert: der, key: key}) do
    key_path = Path.join(dir, name <> ".key")
    File.write!(key_path, "")
    File.chmod!(key_path, 0o600)

    File.write!(
      key_path,
      :public_key.pem_encode([:public_key.pem_entry_encode(:ECPrivateKey, key)])
    )

    File.write!(
      Path.join(dir, name <> ".pem"),
      :public_key.pem_encode([{:Certificate, der, :not_encrypted}])
    )
  end

  @doc """
  The node names accepted by `generate/2`: letters, digits, `_` and `-`, optionally followed by
  `@host`.

  ## Examples

      iex> Tartarus.Security.Certs.valid_node_name?("a@host-1.lab")
      true
      iex> Tartarus.Security.Certs.valid_node_name?("../etc")
      false
  """
  @spec valid_node_name?(term()) :: boolean()
  def valid_node_name?(name) when is_binary(name),
    do: name =~ ~r/\A[A-Za-z0-9_\-]+(@[A-Za-z0-9_\-]+(\.[A-Za-z0-9_\-]+)*)?\z/

  def valid_node_name?(_), do: false

  ## Building certificates

  defp sign(subject, issuer, key, signing_key, days, extensions) do
    {:ECPrivateKey, _, _, _, public_point, _} = key
    # The machine's wall clock, in either mode: :ssl checks a certificate's validity against
    # it (the OS time), never against virtual time, which may run days ahead of it.
    now = Tartarus.Clock.machine_system_time(:second)

    tbs(
      version: :v3,
      serialNumber: :crypto.strong_rand_bytes(8) |> :binary.decode_unsigned() |> Bitwise.bor(1),
      signature: {:SignatureAlgorithm, @ecdsa_with_sha256, :asn1_NOVALUE},
      issuer: issuer,
      validity: {:Validity, time(now - 3600), time(now + days * 86_400)},
      subject: subject,
      subjectPublicKeyInfo:
        {:OTPSubjectPublicKeyInfo,
         {:PublicKeyAlgorithm, @id_ec_public_key, {:namedCurve, @secp256r1}},
         {:ECPoint, public_point}},
      extensions: extensions
    )
    |> :public_key.pkix_sign(signing_key)
  end

  defp new_key, do: :public_key.generate_key({:namedCurve, @secp256r1})

  defp key_id({:ECPrivateKey, _, _, _, public_point, _}),
    do: binary_part(:crypto.hash(:sha, public_point), 0, 20)

  defp subject(common_name) do
    {:rdnSequence,
     [
       [{:AttributeTypeAndValue, @organization, {:utf8String, "Tartarus"}}],
       [{:AttributeTypeAndValue, @common_name, {:utf8String, common_name}}]
     ]}
  end

  defp subject_of(otp_cert) do
    {:OTPCertificate, tbs, _, _} = otp_cert
    tbs(tbs, :subject)
  end

  defp ext(oid, critical, value), do: {:Extension, oid, critical, value}

  # X.509: UTCTime until 2049, GeneralizedTime from 2050.
  defp time(unix) do
    {{y, mo, d}, {h, mi, s}} = :calendar.system_time_to_universal_time(unix, :second)

    digits = :io_lib.format(~c"~2..0w~2..0w~2..0w~2..0w~2..0wZ", [mo, d, h, mi, s])

    if y < 2050,
      do: {:utcTime, ~c"#{pad(rem(y, 100))}#{digits}"},
      else: {:generalTime, ~c"#{y}#{digits}"}
  end

  defp pad(n), do: n |> Integer.to_string() |> String.pad_leading(2, "0")

  # An IP address is listed twice: as `iPAddress`, and as a `dNSName` with its text, which is
  # what OTP 25's hostname check compares the dialled host (a string, also for an address) with.
  defp alt_names(host) do
    case :inet.parse_address(String.to_charlist(host)) do
      {:ok, ip} when tuple_size(ip) == 4 ->
        [{:iPAddress, :erlang.list_to_binary(Tuple.to_list(ip))}, {:dNSName, ~c"#{host}"}]

      {:ok, ip} ->
        [
          {:iPAddress, for(part <- Tuple.to_list(ip), into: <<>>, do: <<part::16>>)},
          {:dNSName, ~c"#{host}"}
        ]

      {:error, _} ->
        [{:dNSName, String.to_charlist(host)}]
    end
  end

  defp host_names(node_name) do
    case String.split(node_name, "@", parts: 2) do
      [_name, host] -> [host]
      [_name] -> []
    end
  end

  ## Files and validation

  defp load_or_create_ca(dir, opts) do
    if File.exists?(Path.join(dir, "ca.pem")) and File.exists?(Path.join(dir, "ca.key")) do
      with {:ok, ca} <- load_ca(dir), do: {:ok, ca, false}
    else
      ca = generate_ca(opts)
      write_pair!(dir, "ca", ca)
      {:ok, ca, true}
    end
  end

  defp validate_nodes(nodes) when is_list(nodes) do
    case Enum.reject(nodes, &valid_node_name?/1) do
      [] ->
        :ok

      bad ->
        {:error,
         "invalid node names: expected letters, digits, _ and -, optionally @host, got: " <>
           Enum.map_join(bad, ", ", &inspect/1)}
    end
  end

  defp validate_nodes(other),
    do: {:error, "invalid option :nodes: expected a list of node names, got: #{inspect(other)}"}

  defp validate_hosts(hosts) when is_list(hosts) do
    case Enum.reject(hosts, &(is_binary(&1) and &1 =~ ~r/\A[A-Za-z0-9_\-.:]+\z/)) do
      [] ->
        :ok

      bad ->
        {:error,
         "invalid option :hosts: expected host names or IP addresses, got: " <>
           Enum.map_join(bad, ", ", &inspect/1)}
    end
  end

  defp validate_hosts(other),
    do: {:error, "invalid option :hosts: expected a list of host names, got: #{inspect(other)}"}

  defp validate_days(days) when is_integer(days) and days > 0, do: :ok

  defp validate_days(days),
    do: {:error, "invalid option :days: expected a positive integer, got: #{inspect(days)}"}

  defp days(opts), do: Keyword.get(opts, :days, @default_days)

  defp mkdir(dir) do
    case File.mkdir_p(dir) do
      :ok -> :ok
      {:error, posix} -> {:error, "cannot create #{dir}: #{:file.format_error(posix)}"}
    end
  end

  defp read(path) do
    case File.read(path) do
      {:ok, data} -> {:ok, data}
      {:error, posix} -> {:error, "cannot read #{path}: #{:file.format_error(posix)}"}
    end
  end
end
