defmodule Tartarus.Security.TrustList do
  @moduledoc """
  The set of issuer public keys a host trusts: the "lock" of Tartarus's lock-and-key.

  A pure struct; the host keeps one and passes it to `Tartarus.Security.Signer` (or to
  `check/4`) for every arriving envelope and module. An issuer not in the list is refused with
  `{:error, {:unknown_issuer, fingerprint}}`, whatever its signature.

      {:ok, trust} = Tartarus.Security.TrustList.from_dir("/etc/tartarus/trusted")
      trust = Tartarus.Security.TrustList.add(trust, other_issuer.public)
      :ok = Tartarus.Security.TrustList.check(trust, issuer, term, signature)

  A trust directory holds one `.pub` file per issuer (32 raw bytes, as written by
  `Tartarus.Security.Keys.save/3`); other files are ignored.
  """

  alias Tartarus.Security.Keys

  defstruct keys: %{}, nodes: MapSet.new()

  @typedoc """
  A trust list: trusted public keys, each with its fingerprint, and the nodes allowed to change
  the host's overlay links (see `trust_node/2`).
  """
  @type t :: %__MODULE__{keys: %{Keys.public_key() => String.t()}, nodes: MapSet.t(node())}

  @doc """
  Builds a trust list from public keys.

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> trust = Tartarus.Security.TrustList.new([keys.public])
      iex> Tartarus.Security.TrustList.member?(trust, keys.public)
      true
  """
  @spec new([Keys.public_key()]) :: t()
  def new(public_keys \\ []), do: Enum.reduce(public_keys, %__MODULE__{}, &add(&2, &1))

  @doc "Trusts one more issuer. Raises `ArgumentError` if `public_key` is not 32 bytes."
  @spec add(t(), Keys.public_key()) :: t()
  def add(%__MODULE__{keys: keys} = trust, public_key) do
    %{trust | keys: Map.put(keys, public_key, Keys.fingerprint(public_key))}
  end

  @doc "Stops trusting an issuer. Removing an unknown key does nothing."
  @spec remove(t(), Keys.public_key()) :: t()
  def remove(%__MODULE__{keys: keys} = trust, public_key) do
    %{trust | keys: Map.delete(keys, public_key)}
  end

  @doc "Whether `public_key` is trusted."
  @spec member?(t(), term()) :: boolean()
  def member?(%__MODULE__{keys: keys}, public_key), do: Map.has_key?(keys, public_key)

  @doc """
  Trusts `node` to change the overlay links of the host that holds this list
  (`{:connect, ...}` and `{:disconnect, ...}` requests). A host accepts such requests from its
  own node always, from another node only if its trust list names that node. With TLS
  distribution (`Tartarus.Security.TLSDist`) a node's name is bound to its certificate, so
  naming a node here names a certificate holder.

      iex> trust = Tartarus.Security.TrustList.new() |> Tartarus.Security.TrustList.trust_node(:"b@host")
      iex> Tartarus.Security.TrustList.node_trusted?(trust, :"b@host")
      true
      iex> Tartarus.Security.TrustList.node_trusted?(trust, :"evil@host")
      false
  """
  @spec trust_node(t(), node()) :: t()
  def trust_node(%__MODULE__{nodes: nodes} = trust, node) when is_atom(node),
    do: %{trust | nodes: MapSet.put(nodes, node)}

  @doc "Whether `node` may change the overlay links of a host holding this list."
  @spec node_trusted?(t(), node()) :: boolean()
  def node_trusted?(%__MODULE__{nodes: nodes}, node), do: MapSet.member?(nodes, node)

  @doc "How many issuers are trusted."
  @spec size(t()) :: non_neg_integer()
  def size(%__MODULE__{keys: keys}), do: map_size(keys)

  @doc "The fingerprints of the trusted issuers, sorted."
  @spec fingerprints(t()) :: [String.t()]
  def fingerprints(%__MODULE__{keys: keys}), do: keys |> Map.values() |> Enum.sort()

  @doc """
  Loads every `*.pub` file in `dir` as a trusted issuer.

  Fails on the first unreadable or malformed key file, naming it; an empty directory gives an
  empty trust list (which trusts nobody).
  """
  @spec from_dir(Path.t()) :: {:ok, t()} | {:error, Keys.load_error()}
  def from_dir(dir) do
    case File.ls(dir) do
      {:ok, names} ->
        names
        |> Enum.filter(&String.ends_with?(&1, ".pub"))
        |> Enum.sort()
        |> Enum.reduce_while({:ok, new()}, fn name, {:ok, trust} ->
          case Keys.load_public(Path.join(dir, name)) do
            {:ok, public} -> {:cont, {:ok, add(trust, public)}}
            {:error, _} = error -> {:halt, error}
          end
        end)

      {:error, posix} ->
        {:error, {:file, dir, posix}}
    end
  end

  @doc """
  Checks that `issuer` is trusted (without checking any signature).

  ## Examples

      iex> Tartarus.Security.TrustList.check_issuer(Tartarus.Security.TrustList.new(), <<0::256>>)
      {:error, {:unknown_issuer, "66687aadf862bd77"}}
  """
  @spec check_issuer(t(), term()) :: :ok | {:error, {:unknown_issuer, String.t()}}
  def check_issuer(%__MODULE__{} = trust, issuer) do
    cond do
      member?(trust, issuer) ->
        :ok

      is_binary(issuer) and byte_size(issuer) == 32 ->
        {:error, {:unknown_issuer, Keys.fingerprint(issuer)}}

      true ->
        {:error, {:unknown_issuer, inspect(issuer)}}
    end
  end

  @doc """
  Checks that `issuer` is trusted and that `signature` is its signature over `term`
  (as made by `Tartarus.Security.Signer.sign/2`).

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> sig = Tartarus.Security.Signer.sign(:hello, keys)
      iex> trust = Tartarus.Security.TrustList.new([keys.public])
      iex> Tartarus.Security.TrustList.check(trust, keys.public, :hello, sig)
      :ok
      iex> Tartarus.Security.TrustList.check(trust, keys.public, :bye, sig)
      {:error, :bad_signature}
  """
  @spec check(t(), Keys.public_key(), term(), binary()) ::
          :ok | {:error, {:unknown_issuer, String.t()}} | {:error, :bad_signature}
  def check(%__MODULE__{} = trust, issuer, term, signature) do
    with :ok <- check_issuer(trust, issuer) do
      Keys.verify(term, signature, issuer)
    end
  end
end
