defmodule Tartarus.Security.Keys do
  @moduledoc """
  Ed25519 issuer keys: the "key" half of Tartarus's lock-and-key.

  An *issuer* (a user, a launcher, a host that creates agents) owns a key pair. It signs every
  agent envelope and every module it ships with the secret key; hosts check the signature with
  the public key and accept only issuers in their `Tartarus.Security.TrustList`. Nothing secret
  ever travels with an agent.

      keys = Tartarus.Security.Keys.generate()
      :ok = Tartarus.Security.Keys.save(keys, "/etc/tartarus/issuer")
      {:ok, ^keys} = Tartarus.Security.Keys.load("/etc/tartarus/issuer")
      Tartarus.Security.Keys.fingerprint(keys.public)
      #=> "3f2a9c01d4e5b6a7"

  ## Files on disk

  `save/3` writes two files into a directory, named after the key (`"issuer"` by default):

    * `issuer.key` - the 32 raw bytes of the Ed25519 secret key, mode `0600`;
    * `issuer.pub` - the 32 raw bytes of the public key, mode `0644`.

  The format is raw bytes, not PEM: OTP 25's `:public_key` has no standard PKCS#8 encoding for
  Ed25519, and raw bytes are trivially checked (`load/2` refuses a file of the wrong size).
  `load/2` also refuses a secret key file readable by group or others, like `ssh` does.
  To trust an issuer, copy its `.pub` file into a host's trust directory
  (see `Tartarus.Security.TrustList.from_dir/1`).
  """

  import Bitwise

  @typedoc "An Ed25519 public key: 32 raw bytes."
  @type public_key :: <<_::256>>

  @typedoc "An Ed25519 secret key (the seed): 32 raw bytes. Never leaves its issuer."
  @type secret_key :: <<_::256>>

  @typedoc "An issuer's key pair."
  @type t :: %{public: public_key(), secret: secret_key()}

  @typedoc "Why keys could not be loaded."
  @type load_error ::
          {:file, Path.t(), File.posix()}
          | {:bad_key_size, Path.t(), expected :: 32, got :: non_neg_integer()}
          | {:insecure_permissions, Path.t(), mode :: non_neg_integer()}
          | {:key_mismatch, Path.t()}

  @key_bytes 32

  @doc """
  Generates a fresh Ed25519 key pair with `:crypto`.

  ## Examples

      iex> %{public: pub, secret: sec} = Tartarus.Security.Keys.generate()
      iex> {byte_size(pub), byte_size(sec)}
      {32, 32}
  """
  @spec generate() :: t()
  def generate do
    {public, secret} = :crypto.generate_key(:eddsa, :ed25519)
    %{public: public, secret: secret}
  end

  @doc """
  Derives the public key from a secret key.

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> Tartarus.Security.Keys.public_from_secret(keys.secret) == keys.public
      true
  """
  @spec public_from_secret(secret_key()) :: public_key()
  def public_from_secret(<<_::binary-size(@key_bytes)>> = secret) do
    {public, ^secret} = :crypto.generate_key(:eddsa, :ed25519, secret)
    public
  end

  def public_from_secret(other) do
    raise ArgumentError,
          "expected an Ed25519 secret key (32 bytes), got: #{describe(other)}"
  end

  @doc """
  A short, human-readable name for a public key: the first 8 bytes of its SHA-256, in hex.

  Used in logs, events and errors such as `{:unknown_issuer, fingerprint}`.

  ## Examples

      iex> Tartarus.Security.Keys.fingerprint(<<0::256>>)
      "66687aadf862bd77"
  """
  @spec fingerprint(public_key()) :: String.t()
  def fingerprint(<<_::binary-size(@key_bytes)>> = public) do
    <<short::binary-size(8), _::binary>> = :crypto.hash(:sha256, public)
    Base.encode16(short, case: :lower)
  end

  def fingerprint(other) do
    raise ArgumentError,
          "expected an Ed25519 public key (32 bytes), got: #{describe(other)}"
  end

  @doc """
  Writes `keys` into `dir` as `<name>.key` (mode 0600) and `<name>.pub` (mode 0644).

  Creates `dir` if needed. Existing files are overwritten.
  """
  @spec save(t(), Path.t(), String.t()) :: :ok | {:error, {:file, Path.t(), File.posix()}}
  def save(%{public: public, secret: secret}, dir, name \\ "issuer") do
    key_path = Path.join(dir, name <> ".key")
    pub_path = Path.join(dir, name <> ".pub")

    with :ok <- file_op(dir, &File.mkdir_p/1),
         :ok <- write_private(key_path, secret),
         :ok <- file_op(pub_path, &File.write(&1, public)) do
      file_op(pub_path, &File.chmod(&1, 0o644))
    end
  end

  @doc """
  Like `save/3` but raises `File.Error` on failure.
  """
  @spec save!(t(), Path.t(), String.t()) :: :ok
  def save!(keys, dir, name \\ "issuer") do
    case save(keys, dir, name) do
      :ok ->
        :ok

      {:error, {:file, path, reason}} ->
        raise File.Error, reason: reason, action: "write key file", path: path
    end
  end

  @doc """
  Reads the key pair `<name>.key` / `<name>.pub` from `dir`.

  Fails if a file is missing, has the wrong size, if the secret key is readable by group or
  others, or if the public key does not belong to the secret key.
  """
  @spec load(Path.t(), String.t()) :: {:ok, t()} | {:error, load_error()}
  def load(dir, name \\ "issuer") do
    key_path = Path.join(dir, name <> ".key")
    pub_path = Path.join(dir, name <> ".pub")

    with {:ok, %File.Stat{mode: mode}} <- file_op(key_path, &File.stat/1),
         :ok <- check_private_mode(key_path, mode),
         {:ok, secret} <- read_key(key_path),
         {:ok, public} <- read_key(pub_path) do
      if public_from_secret(secret) == public do
        {:ok, %{public: public, secret: secret}}
      else
        {:error, {:key_mismatch, pub_path}}
      end
    end
  end

  @doc """
  Like `load/2` but raises `ArgumentError` with a readable message on failure.
  """
  @spec load!(Path.t(), String.t()) :: t()
  def load!(dir, name \\ "issuer") do
    case load(dir, name) do
      {:ok, keys} -> keys
      {:error, reason} -> raise ArgumentError, format_error(reason)
    end
  end

  @doc """
  Reads one public key file (32 raw bytes), such as a `.pub` file written by `save/3`.
  """
  @spec load_public(Path.t()) :: {:ok, public_key()} | {:error, load_error()}
  def load_public(path), do: read_key(path)

  @doc """
  Turns a `t:load_error/0` into a sentence.

  ## Examples

      iex> Tartarus.Security.Keys.format_error({:bad_key_size, "k.pub", 32, 5})
      "invalid key file k.pub: expected 32 raw bytes, got: 5 bytes"
  """
  @spec format_error(load_error()) :: String.t()
  def format_error({:file, path, posix}),
    do: "cannot access key file #{path}: #{:file.format_error(posix)}"

  def format_error({:bad_key_size, path, expected, got}),
    do: "invalid key file #{path}: expected #{expected} raw bytes, got: #{got} bytes"

  def format_error({:insecure_permissions, path, mode}),
    do:
      "insecure key file #{path}: expected mode 0600 (no access for group or others), " <>
        "got: 0#{Integer.to_string(mode &&& 0o777, 8)}"

  def format_error({:key_mismatch, path}),
    do: "public key #{path} does not belong to the secret key beside it"

  defp read_key(path) do
    with {:ok, bytes} <- file_op(path, &File.read/1) do
      case byte_size(bytes) do
        @key_bytes -> {:ok, bytes}
        n -> {:error, {:bad_key_size, path, @key_bytes, n}}
      end
    end
  end

  defp check_private_mode(path, mode) do
    if (mode &&& 0o077) == 0, do: :ok, else: {:error, {:insecure_permissions, path, mode}}
  end

  # Creates the file with mode 0600 before the secret is written into it.
  defp write_private(path, secret) do
    with :ok <- file_op(path, &File.write(&1, "")),
         :ok <- file_op(path, &File.chmod(&1, 0o600)) do
      file_op(path, &File.write(&1, secret))
    end
  end

  defp file_op(path, fun) do
    case fun.(path) do
      {:error, posix} -> {:error, {:file, path, posix}}
      other -> other
    end
  end

  defp describe(bin) when is_binary(bin), do: "a binary of #{byte_size(bin)} bytes"
  defp describe(other), do: inspect(other)

  @doc """
  The canonical bytes of `term`, the ones a signature covers (deterministic external term
  format, so equal terms give equal bytes).

  ## Examples

      iex> a = Tartarus.Security.Keys.canonical(%{b: 1, a: 2})
      iex> a == Tartarus.Security.Keys.canonical(Map.new([{:a, 2}, {:b, 1}]))
      true
  """
  @spec canonical(term()) :: binary()
  def canonical(term), do: :erlang.term_to_binary(term, [:deterministic, minor_version: 2])

  @doc """
  Checks that `signature` was made over `term` by the owner of `public_key` (a signature made
  by `Tartarus.Security.Signer.sign/2`). Returns `{:error, :bad_signature}` for any mismatch,
  including a malformed signature or key.

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> sig = Tartarus.Security.Signer.sign(:hello, keys)
      iex> Tartarus.Security.Keys.verify(:hello, sig, keys.public)
      :ok
      iex> Tartarus.Security.Keys.verify(:bye, sig, keys.public)
      {:error, :bad_signature}
  """
  @spec verify(term(), binary(), public_key()) :: :ok | {:error, :bad_signature}
  def verify(term, signature, public_key)
      when is_binary(signature) and byte_size(signature) == 64 and is_binary(public_key) and
             byte_size(public_key) == 32 do
    bytes = "tartarus/term/v1" <> canonical(term)

    if :crypto.verify(:eddsa, :none, bytes, signature, [public_key, :ed25519]),
      do: :ok,
      else: {:error, :bad_signature}
  end

  def verify(_term, _signature, _public_key), do: {:error, :bad_signature}
end
