defmodule Tartarus.Test.Probe do
  @moduledoc false
  # A general-purpose agent for tests. Its state is a map; it reports what happens to it to
  # the process in its payload under `:test` (so it can report even after a restart from a
  # snapshot): {:probe_init, id, state}, {:probe_arrived, id, ctx, state},
  # {:probe_move_failed, id, dest, reason, ctx}, {:probe_plugin_event, id, plugin, event}.
  #
  # Messages (posts or requests):
  #   :inc                  count + 1
  #   :state                replies with the state
  #   {:agent, fun, args}   replies with apply(Tartarus.Agent, fun, args)
  #   {:set, key, value}    puts key in the state
  #   {:do, action}         carries out action: {:move, dest} | {:clone, dest} |
  #                         {:return, result} | {:stop, reason} | :stay
  #   :crash                raises
  #   :ignore               never replies
  #   {:answer_from, dest}  moves to dest and answers the request from there with its host
  #   {:timed_request, agent, msg}
  #                         requests msg from agent, replies {result, elapsed ms}
  #
  # Init args: a map merged into the default state; `init_action:` is carried out at once,
  # `arrival_action:` on every arrival.
  use Tartarus.Agent

  alias Tartarus.Agent, as: A

  @defaults %{count: 0, arrivals: [], failures: [], ctx: nil}

  @impl true
  def init(:raise), do: raise("init failed on purpose")

  def init(args) when is_map(args) do
    s = Map.merge(@defaults, args)
    notify({:probe_init, A.id(), s})

    case s do
      %{init_action: action} -> action(action, s)
      _ -> {:stay, s}
    end
  end

  @impl true
  def handle_arrival(ctx, s) do
    notify({:probe_arrived, A.id(), ctx, s})

    case s do
      %{arrivals: arrivals} ->
        s = %{s | ctx: ctx, arrivals: arrivals ++ [ctx.host]}
        {pending, s} = Map.pop(s, :pending)
        if pending, do: A.reply(pending, A.host())

        case s do
          %{arrival_action: action} -> action(action, s)
          _ -> {:stay, s}
        end

      _ ->
        {:stay, s}
    end
  end

  @impl true
  def handle_message(:inc, _from, s), do: {:stay, Map.update!(s, :count, &(&1 + 1))}
  def handle_message(:state, from, s), do: reply(from, s, s)
  def handle_message({:agent, fun, args}, from, s), do: reply(from, apply(A, fun, args), s)
  def handle_message({:set, key, value}, from, s), do: reply(from, :ok, Map.put(s, key, value))
  def handle_message(:crash, _from, _s), do: raise("probe crash on purpose")
  def handle_message(:ignore, _from, s), do: {:stay, s}
  def handle_message({:answer_from, dest}, from, s), do: {:move, dest, Map.put(s, :pending, from)}

  def handle_message({:timed_request, agent, msg}, from, s) do
    t0 = System.monotonic_time(:millisecond)
    result = Tartarus.request(agent, msg)
    reply(from, {result, System.monotonic_time(:millisecond) - t0}, s)
  end

  def handle_message({:do, action}, from, s) do
    A.reply(from, :ok)
    action(action, s)
  end

  @impl true
  def handle_move_failed(dest, reason, ctx, s) do
    notify({:probe_move_failed, A.id(), dest, reason, ctx})
    {:stay, Map.update(s, :failures, [{dest, reason}], &(&1 ++ [{dest, reason}]))}
  end

  @impl true
  def handle_info({:plugin_event, plugin, event}, s) do
    notify({:probe_plugin_event, A.id(), plugin, event})
    {:stay, s}
  end

  # Ballast, to outgrow a host's max_heap_size.
  def handle_info({:grow, n}, s), do: {:stay, Map.put(s, :ballast, Enum.to_list(1..n))}
  def handle_info(_other, s), do: {:stay, s}

  defp action({:move, dest}, s), do: {:move, dest, s}
  defp action({:clone, dest}, s), do: {:clone, dest, s}
  defp action({:return, result}, s), do: {:return, result, s}
  defp action({:stop, reason}, s), do: {:stop, reason, s}
  defp action(:stay, s), do: {:stay, s}
  defp action(other, _s), do: other

  defp reply(from, value, s) do
    A.reply(from, value)
    {:stay, s}
  end

  defp notify(msg) do
    case A.payload() do
      %{test: pid} when is_pid(pid) -> send(pid, msg)
      _ -> :ok
    end
  end
end

defmodule Tartarus.Test.Walker do
  @moduledoc false
  # Walks `moves` hops with a strategy and returns the hosts it arrived at, in order, to its
  # owner. A failed move returns `{:failed, reason, path}`.
  use Tartarus.Agent

  @impl true
  def init({strategy, moves}), do: {:move, strategy, %{strategy: strategy, left: moves, path: []}}

  @impl true
  def handle_arrival(ctx, s) do
    s = %{s | left: s.left - 1, path: s.path ++ [ctx.host]}
    if s.left == 0, do: {:return, s.path, s}, else: {:move, s.strategy, s}
  end

  @impl true
  def handle_move_failed(_dest, reason, _ctx, s), do: {:return, {:failed, reason, s.path}, s}
end

defmodule Tartarus.Test.PickStrategy do
  @moduledoc false
  # A user strategy: goes to the neighbour named `name`, if there is one.
  @behaviour Tartarus.Strategy

  @impl true
  def choose(name, info, rng) do
    case Enum.find(info.neighbours, fn {n, _} -> n == name end) do
      nil -> {:error, {:no_such_neighbour, name}}
      dest -> {:ok, dest, rng}
    end
  end
end

defmodule Tartarus.Test.FailingPlugin do
  @moduledoc false
  # A plugin whose device never opens.
  @behaviour Tartarus.Plugin

  @impl true
  def init(_opts), do: {:error, :no_device}

  @impl true
  def describe(_s), do: %{kind: :broken}

  @impl true
  def read(_args, s), do: {:ok, nil, s}

  @impl true
  def write(_args, s), do: {:ok, s}
end

defmodule Tartarus.Test.CrashingPlugin do
  @moduledoc false
  # A plugin that crashes on `read(:crash)`.
  @behaviour Tartarus.Plugin

  @impl true
  def init(_opts), do: {:ok, nil}

  @impl true
  def describe(_s), do: %{kind: :crashing}

  @impl true
  def read(:crash, _s), do: raise("plugin crash on purpose")
  def read(_args, s), do: {:ok, :fine, s}

  @impl true
  def write(_args, s), do: {:ok, s}
end

defmodule Tartarus.Test.NotAPlugin do
  @moduledoc false
  # Has no read/2: not a plugin.
  def init(_opts), do: {:ok, nil}
end

defmodule Tartarus.Test.CutLinks do
  @moduledoc false
  # A transport (Tartarus.Transport) that fails hand-offs over one link, named in
  # :persistent_term {__MODULE__, :cut} as {from, to, test_pid}, and tells the test what the
  # link's properties were; every other hand-off and message passes untouched.
  @behaviour Tartarus.Transport

  @impl true
  def hand_off(host, dest, rng) do
    case :persistent_term.get({__MODULE__, :cut}, nil) do
      {from, ^dest, pid} when from == host.ref ->
        send(pid, {:cut_links, Tartarus.Transport.link(host, dest)})
        {:error, :link_cut, rng}

      _ ->
        {:ok, rng}
    end
  end

  @impl true
  def message_delay(_from, _to), do: 0
end

defmodule Tartarus.Test.LogSpy do
  @moduledoc false
  # A :logger handler for tests: sends every event that passed the primary filters to the
  # pid in its `config` (`:logger.add_handler(id, Tartarus.Test.LogSpy, %{config: self()})`).
  def log(event, %{config: pid}), do: send(pid, {:logged, event})
end
