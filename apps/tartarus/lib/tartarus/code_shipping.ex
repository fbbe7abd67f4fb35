defmodule Tartarus.CodeShipping do
  @moduledoc false
  # Shipping an agent's code to another node: the one implementation both the facade (an
  # agent created on a remote host) and a migration (`Tartarus.Agent.Server`, when the
  # destination answers `{:"$tartarus_need", mig, modules}`) use. Code travels as
  # `{module, md5, binary}` triples, checked against the md5 of a manifest
  # (`Tartarus.CodeCache.manifest/1`) and loaded by `Tartarus.CodeCache.load/1` at the
  # other end.

  alias Tartarus.CodeCache

  @doc false
  # The `{module, md5, binary}` triples of `mods`, each at the md5 `manifest` names.
  @spec binaries([{module(), binary()}], [module()]) ::
          {:ok, [{module(), binary(), binary()}]} | {:error, term()}
  def binaries(manifest, mods) do
    Enum.reduce_while(mods, {:ok, []}, fn mod, {:ok, acc} ->
      with {_, md5} <- List.keyfind(manifest, mod, 0),
           {:ok, bin} <- CodeCache.fetch_binary(mod, md5) do
        {:cont, {:ok, [{mod, md5, bin} | acc]}}
      else
        nil -> {:halt, {:error, {:not_in_manifest, mod}}}
        error -> {:halt, error}
      end
    end)
  end

  @doc false
  # Makes sure `node` has `modules` at the versions this node runs: asks it which it
  # lacks and sends those. `:ok` at once for this node.
  @spec ensure(node(), [module()]) :: :ok | {:error, term()}
  def ensure(node, _modules) when node == node(), do: :ok

  def ensure(node, modules) do
    with {:ok, manifest} <- CodeCache.manifest(modules) do
      case :erpc.call(node, CodeCache, :check, [manifest], 10_000) do
        :ok ->
          :ok

        {:need, mods} ->
          with {:ok, code} <- binaries(manifest, mods),
               do: :erpc.call(node, CodeCache, :load, [code], 30_000)

        error ->
          error
      end
    end
  catch
    _, _ -> {:error, {:unknown_host, {:node, node}}}
  end
end
