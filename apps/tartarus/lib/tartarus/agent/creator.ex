defmodule Tartarus.Agent.Creator do
  @moduledoc false
  # Creating an agent: options checked (`Tartarus.Options.Platform.create_agent/1`), the
  # envelope built and, with `issuer:`, signed; the agent's code shipped to the host's node
  # if that is another one (like a migration would); then the host starts it (a host of this
  # node without a call to its server: Tartarus.Host.Agents.create_local/4).

  alias Tartarus.{CodeCache, Envelope, Host}

  @doc false
  @spec create(term(), module(), term(), keyword()) :: {:ok, String.t()} | {:error, term()}
  def create(host, module, args, opts) do
    with {:ok, opts} <- Tartarus.Options.Platform.create_agent(opts),
         :ok <- check_agent_module(module),
         :ok <- check_payload(opts[:payload]),
         host = Host.address(host),
         {:ok, env} <- sign(new_envelope(host, module, opts), opts[:issuer]),
         :ok <- Tartarus.CodeShipping.ensure(elem(host, 1), Envelope.modules(env)) do
      start(host, env, args)
    end
  end

  defp start({_, node} = host, env, args) when node == node() do
    case Host.local(host) do
      {:ok, info} ->
        try do
          Tartarus.Host.Agents.create_local(info, env, args, 30_000)
        rescue
          # The host stopped while we wrote to its table.
          ArgumentError -> {:error, {:unknown_host, host}}
        end

      error ->
        error
    end
  end

  defp start(host, env, args), do: Host.call(host, {:create, env, args}, 30_000)

  defp check_agent_module(module) do
    if Tartarus.Agent.agent_module?(module), do: :ok, else: {:error, {:not_an_agent, module}}
  end

  defp sign(env, nil), do: {:ok, env}

  defp sign(env, keys) do
    if Tartarus.Security.keys?(keys) do
      with {:ok, manifest} <- CodeCache.manifest(Envelope.modules(env)),
           do: {:ok, Tartarus.Security.issue(env, manifest, keys)}
    else
      {:error,
       "invalid options given to Tartarus.create_agent/4 for key :issuer: expected a key pair, got: #{inspect(keys)}"}
    end
  end

  defp check_payload(p), do: Envelope.portable?(p)

  defp new_envelope(host, module, opts) do
    id = Envelope.new_id()

    %Envelope{
      id: id,
      name: opts[:name] || Tartarus.Envelope.default_name(module, id),
      module: module,
      ships: module.__tartarus_agent__(:ships),
      payload: %{data: opts[:payload], modules: opts[:modules]},
      owner: opts[:owner],
      home: host,
      ttl: opts[:ttl],
      static: opts[:static],
      rng: Envelope.seed_rng(Keyword.get(opts, :seed, id))
    }
  end
end
