defmodule TartarusEmu.FreshVM do
  @moduledoc """
  Runs a function in a fresh BEAM of its own (a `:peer` started for it and stopped after):
  the one way found to make a run in virtual time replay exactly when other runs came
  before it in the same VM.

  ## Why

  A run in virtual time (`Tartarus.Clock.Virtual`) is replayed exactly from its seed when it
  runs alone in a VM: the 60-task blind agents' floor of the warehouse's Fig. 4.4, seed
  2101, gave identical figures in five of five fresh VMs (2026-12-06), whatever pid and
  reference counters it started from. The same floor run after thirteen others in one VM
  gave one of two outcomes (97.63 or 97.80 hops a task) in two whole-seed runs of two. What
  a VM keeps from one run to the next (heaps of long-lived services, the timers' arming
  sequence of one clock installed around several runs, tables grown and shrunk) is not the
  seed's, so a run that shares a VM with earlier ones is a function of them too.

  ## How

  The peer is connected through its standard input and output (`connection:
  :standard_io`: no distribution, no epmd), started with this VM's code path; the
  configuration of every application loaded here is copied to it before it starts
  `apps` (default `[:tartarus]`). The function is sent to it and called there; its
  result comes back compressed. Output the function prints is forwarded to this VM.
  An exception in the function is raised again here, with the peer's stack trace.

  The function must be one the peer can load: a function of a compiled module whose
  `.beam` is on the code path (`portable?/1` tells), not one defined in a script or a test
  file. Whatever it captures is copied to the peer, and what it returns back here: pids,
  references and ETS tables of this VM mean nothing there.

      iex> TartarusEmu.FreshVM.run(&System.schedulers_online/0) >= 1
      true
  """

  # The VM's own and the build tool's: the peer boots with its own.
  @not_copied [:kernel, :stdlib, :compiler, :elixir, :mix, :iex, :hex, :ex_unit]

  @typedoc "Options of `run/2`."
  @type option :: {:apps, [atom()]} | {:timeout, timeout()}

  @doc """
  Calls `fun` (a function of arity 0, or `{module, function, args}`) in a fresh VM and
  returns its result. Options: `:apps`, the applications started in the peer before the
  call (with their dependencies; default `[:tartarus]`), `:timeout` (default `:infinity`).
  Raises `ArgumentError` for a function the peer could not load (`portable?/1`).
  """
  @spec run((() -> result) | {module(), atom(), list()}, [option()]) :: result
        when result: term()
  def run(fun, opts \\ [])

  def run({m, f, a}, opts) when is_atom(m) and is_atom(f) and is_list(a),
    do: run(fn -> apply(m, f, a) end, opts)

  def run(fun, opts) when is_function(fun, 0) do
    unless portable?(fun),
      do:
        raise(ArgumentError,
          message:
            "TartarusEmu.FreshVM.run/2 needs a function a fresh VM can load (of a compiled " <>
              "module on the code path, capturing only such functions), got: #{inspect(fun)}"
        )

    apps = Keyword.get(opts, :apps, [:tartarus])
    timeout = Keyword.get(opts, :timeout, :infinity)

    env =
      for {app, _, _} <- Application.loaded_applications(),
          app not in @not_copied,
          do: {app, Application.get_all_env(app)}

    paths =
      :code.get_path()
      |> Enum.reject(&(&1 == ~c"."))
      |> Enum.flat_map(&[~c"-pa", &1])

    {:ok, peer, _node} =
      :peer.start_link(%{connection: :standard_io, args: paths, wait_boot: 120_000})

    try do
      reply = :peer.call(peer, __MODULE__, :__call__, [env, apps, fun], timeout)

      case :erlang.binary_to_term(reply) do
        {:ok, result} -> result
        {:raised, kind, reason, stack} -> :erlang.raise(kind, reason, stack)
      end
    after
      :peer.stop(peer)
    end
  end

  @doc """
  True if `term` (a function, or data holding functions) can be called in a fresh VM:
  every function in it is an external one (`&Mod.fun/arity`) or a closure of a module whose
  `.beam` is on the code path, and so is every function it captures.
  """
  @spec portable?(term()) :: boolean()
  def portable?(f) when is_function(f) do
    case Function.info(f, :type) do
      {:type, :external} ->
        true

      {:type, :local} ->
        {:module, m} = Function.info(f, :module)
        {:env, captured} = Function.info(f, :env)
        on_disk?(m) and Enum.all?(captured, &portable?/1)
    end
  end

  def portable?(t) when is_tuple(t), do: t |> Tuple.to_list() |> portable?()
  def portable?([h | t]), do: portable?(h) and portable?(t)
  def portable?(%{} = m), do: m |> :maps.to_list() |> portable?()
  def portable?(_), do: true

  defp on_disk?(m) do
    case :code.which(m) do
      path when is_list(path) -> File.regular?(path)
      _ -> false
    end
  end

  @doc false
  # Runs in the peer: the configuration, the applications, then the function.
  @spec __call__([{atom(), keyword()}], [atom()], (() -> term())) :: binary()
  def __call__(env, apps, fun) do
    for {app, kv} <- env, kv != [] do
      _ = Application.load(app)
      Application.put_all_env([{app, kv}])
    end

    for app <- apps, do: {:ok, _} = Application.ensure_all_started(app)

    result =
      try do
        {:ok, fun.()}
      catch
        kind, reason -> {:raised, kind, reason, __STACKTRACE__}
      end

    :erlang.term_to_binary(result, [:compressed])
  end
end
