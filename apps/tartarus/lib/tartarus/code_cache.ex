defmodule Tartarus.CodeCache do
  @moduledoc """
  The node's cache of agent code: BEAM binaries by module and md5.

  Agents travel with the list of modules they need (their own module, the modules named by
  `use Tartarus.Agent, ships: [...]`, and modules in their payload). Each module is described
  by its md5 (`module.module_info(:md5)`, the same value `:beam_lib.md5/1` computes from the
  binary). A destination asks only for the modules it lacks, so a module crosses a link once.

  Where binaries come from, in order:

    1. this cache: binaries received from other nodes, and modules compiled at run time
       (`use Tartarus.Agent` registers every agent module compiled while the application
       runs, e.g. typed in iex; `Tartarus.compile_string/1` registers every module it
       compiles) — this is on-the-fly programming;
    2. the code path (`:code.get_object_code/1`), for modules compiled by mix.

  Loading a different version of a module that live agents of this node still run is refused
  with `{:code_conflict, module}`; the running agents are never killed to make room. A module
  is reloaded only when no agent runs it and no process runs its old code.
  """
  use GenServer

  @table __MODULE__

  @typedoc "A module and the md5 of its code."
  @type manifest :: [{module(), binary()}]

  @doc false
  def start_link(_), do: GenServer.start_link(__MODULE__, nil, name: __MODULE__)

  @doc """
  Remembers `binary` as the code of `module`, so it can ship to other nodes.
  Used for modules compiled at run time, which have no file on the code path.
  """
  @spec remember(module(), binary()) :: :ok
  def remember(module, binary) when is_atom(module) and is_binary(binary) do
    if :ets.whereis(@table) != :undefined do
      {:ok, {^module, md5}} = :beam_lib.md5(binary)
      :ets.insert(@table, {module, md5, binary})
    end

    :ok
  end

  @doc """
  The manifest of `modules`: each with the md5 of its loaded code.
  Returns `{:error, {:not_loaded, module}}` for a module that is not loaded and not available.
  """
  @spec manifest([module()]) :: {:ok, manifest()} | {:error, {:not_loaded, module()}}
  def manifest(modules) do
    Enum.reduce_while(modules, {:ok, []}, fn mod, {:ok, acc} ->
      case md5(mod) do
        {:ok, md5} -> {:cont, {:ok, [{mod, md5} | acc]}}
        :error -> {:halt, {:error, {:not_loaded, mod}}}
      end
    end)
    |> case do
      {:ok, list} -> {:ok, Enum.reverse(list)}
      error -> error
    end
  end

  @doc "The md5 of the loaded code of `module`, loading it from the code path if needed."
  @spec md5(module()) :: {:ok, binary()} | :error
  def md5(module) do
    case :code.ensure_loaded(module) do
      {:module, _} -> {:ok, module.module_info(:md5)}
      _ -> :error
    end
  end

  @doc """
  The BEAM binary of `module` with md5 `md5`, from the cache or the code path.
  """
  @spec fetch_binary(module(), binary()) ::
          {:ok, binary()} | {:error, {:no_object_code, module()}}
  def fetch_binary(module, md5) do
    case :ets.lookup(@table, module) do
      [{^module, ^md5, bin}] ->
        {:ok, bin}

      _ ->
        with {^module, bin, _file} <- :code.get_object_code(module),
             {:ok, {^module, ^md5}} <- :beam_lib.md5(bin) do
          :ets.insert(@table, {module, md5, bin})
          {:ok, bin}
        else
          _ -> {:error, {:no_object_code, module}}
        end
    end
  end

  @doc """
  Checks a manifest against the code of this node. Returns `:ok` when every module is
  loaded in the same version, `{:need, modules}` for the modules to ship, or
  `{:error, {:code_conflict, module}}` when a different version runs in live agents.
  """
  @spec check(manifest()) :: :ok | {:need, [module()]} | {:error, {:code_conflict, module()}}
  def check(manifest) do
    Enum.reduce_while(manifest, [], fn {mod, md5}, need ->
      case md5(mod) do
        {:ok, ^md5} ->
          {:cont, need}

        {:ok, _other} ->
          if replaceable?(mod),
            do: {:cont, [mod | need]},
            else: {:halt, {:error, {:code_conflict, mod}}}

        :error ->
          {:cont, [mod | need]}
      end
    end)
    |> case do
      [] -> :ok
      need when is_list(need) -> {:need, Enum.reverse(need)}
      error -> error
    end
  end

  @doc """
  Loads shipped modules (a list of `{module, md5, binary}`) after checking each binary's md5.
  Loads go through the cache's process, one at a time, so two hosts receiving the same
  module do not race.
  """
  @spec load([{module(), binary(), binary()}]) :: :ok | {:error, term()}
  def load(modules), do: GenServer.call(__MODULE__, {:load, modules}, 30_000)

  @doc false
  # Creates the cache's table, owned by the application's process (called from
  # Tartarus.Application.start/2): binaries of modules compiled at run time survive a restart
  # of the cache's server.
  def setup do
    if :ets.whereis(@table) == :undefined do
      :ets.new(@table, [:named_table, :public, :set, read_concurrency: true])
    end

    :ok
  end

  @impl true
  def init(nil), do: {:ok, nil}

  # Anything else, from this node or another, is dropped and counted (Tartarus.Events.drop/3):
  # a junk message never stops the cache.
  @impl true
  def handle_call({:load, modules}, from, state) when is_list(modules) do
    Tartarus.Events.reply(from, do_load(modules))
    {:noreply, state}
  end

  def handle_call(msg, from, state) do
    Tartarus.Events.drop(__MODULE__, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, state}
  end

  @impl true
  def handle_cast(msg, state) do
    Tartarus.Events.drop(__MODULE__, :cast, msg)
    {:noreply, state}
  end

  @impl true
  def handle_info(msg, state) do
    Tartarus.Events.drop(__MODULE__, :info, msg)
    {:noreply, state}
  end

  defp do_load([]), do: :ok

  defp do_load([{mod, md5, bin} | rest])
       when is_atom(mod) and is_binary(md5) and is_binary(bin) do
    with {:ok, {^mod, ^md5}} <- safe_md5(bin),
         :ok <- load_one(mod, md5, bin) do
      :ets.insert(@table, {mod, md5, bin})
      do_load(rest)
    else
      {:ok, _} -> {:error, {:bad_md5, mod}}
      {:error, _} = error -> error
    end
  end

  defp do_load([other | _]), do: {:error, {:bad_code, other}}
  defp do_load(other), do: {:error, {:bad_code, other}}

  defp safe_md5(bin) do
    case :beam_lib.md5(bin) do
      {:ok, _} = ok -> ok
      {:error, :beam_lib, reason} -> {:error, {:bad_beam, reason}}
    end
  catch
    kind, reason -> {:error, {:bad_beam, {kind, reason}}}
  end

  defp load_one(mod, md5, bin) do
    case md5(mod) do
      {:ok, ^md5} ->
        :ok

      other ->
        if other == :error or replaceable?(mod) do
          case :code.load_binary(mod, ~c"tartarus:shipped", bin) do
            {:module, ^mod} -> :ok
            {:error, reason} -> {:error, {:load_failed, mod, reason}}
          end
        else
          {:error, {:code_conflict, mod}}
        end
    end
  end

  # A loaded module may be replaced only if no live agent of this node runs it and no process
  # still runs its old code (so loading cannot kill anybody).
  defp replaceable?(mod) do
    not Tartarus.AgentTable.running?(mod) and :code.soft_purge(mod)
  end
end
