defmodule Tartarus.Host.Starter do
  @moduledoc false
  # Builds and tears down a host's process tree (`Tartarus.Host.Supervisor` under the node's
  # `Tartarus.Application.hosts/0`), then brings the new host up to its options: plugins attached,
  # neighbours linked, agents restored from its data directory. Options are validated by
  # `Tartarus.Options.Platform.host/1` before the tree is built, so a bad option starts
  # nothing.

  require Tartarus.Clock
  alias Tartarus.Host

  @doc false
  @spec start(Host.name(), keyword()) :: {:ok, Host.t()} | {:error, term()}
  def start(name, opts) do
    with :ok <- check_name(name),
         {:ok, opts} <- Tartarus.Options.Platform.host(opts) do
      start_tree(name, opts, 1)
    end
  end

  # The warden of a host whose supervisor was killed may still be ending (it kills the
  # host's agents and closes the journal): waited for, once, then the host starts.
  defp start_tree(name, opts, tries) do
    case DynamicSupervisor.start_child(Tartarus.Application.hosts(), %{
           id: name,
           start: {Tartarus.Host.Supervisor, :start_link, [{name, opts}]},
           type: :supervisor,
           restart: :temporary
         }) do
      {:ok, _} ->
        host = Host.address(name)

        with :ok <- attach_all(host, opts[:plugins]),
             :ok <- connect_all(host, opts[:neighbours]),
             {:ok, _agents, _in_doubt} <- Host.call(host, :restore, 60_000) do
          {:ok, host}
        else
          error ->
            Host.OnNode.stop_host(host)
            error
        end

      {:error, {:already_started, _}} ->
        {:error, {:already_started, Host.address(name)}}

      {:error, {:shutdown, {:failed_to_start_child, :warden, {:already_started, old}}}}
      when tries > 0 ->
        ref = Process.monitor(old)

        Tartarus.Clock.receive do
          {:DOWN, ^ref, :process, _, _} -> start_tree(name, opts, tries - 1)
        after
          5_000 ->
            Process.demonitor(ref, [:flush])
            {:error, {:already_started, Host.address(name)}}
        end

      {:error, {:shutdown, {:failed_to_start_child, _, {:already_started, _}}}} ->
        {:error, {:already_started, Host.address(name)}}

      # Its data directory cannot be made, read or written: one error naming it.
      {:error, {:shutdown, {:failed_to_start_child, :warden, {:journal, _, _} = why}}} ->
        {:error, why}

      {:error, reason} ->
        {:error, reason}
    end
  end

  @doc false
  # The hosts running on this node, sorted.
  @spec hosts() :: [Host.t()]
  def hosts do
    Registry.select(Tartarus.HostRegistry, [{{{:host, :"$1"}, :_, :_}, [], [:"$1"]}])
    |> Enum.map(&Host.address/1)
    |> Enum.sort()
  end

  defp check_name(name) do
    if Host.address?(name) and not is_tuple(name),
      do: :ok,
      else:
        {:error,
         "invalid host name given to Tartarus.start_host/2: expected an atom or a string, got: #{inspect(name)}"}
  end

  defp attach_all(host, plugins) do
    Enum.reduce_while(plugins, :ok, fn {name, spec}, :ok ->
      case Host.OnNode.attach_plugin(host, name, spec) do
        :ok -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  defp connect_all(host, neighbours) do
    Enum.reduce_while(neighbours, :ok, fn n, :ok ->
      case Host.Links.connect(host, n, []) do
        :ok -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end
end
