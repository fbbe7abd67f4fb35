defmodule Tartarus.HostCase do
  @moduledoc false
  # Case template for tests that run virtual hosts in this VM.
  #
  # Hosts started with `host!/1` and friends get unique names and are stopped when the test
  # ends. After every test (and after those hosts are stopped) the template checks that
  # nothing leaked: `Tartarus.hosts()` and the number of registered agents are back to what
  # they were before the test. Tests that start hosts with `Tartarus.start_host/2` directly
  # must stop them themselves, or the check fails.
  #
  # Tests using this template must not be `async: true`: the leak check looks at the whole
  # node.
  use ExUnit.CaseTemplate

  import Tartarus.TestSupport, only: [wait_for: 2]

  alias Tartarus.Test.Probe

  using do
    quote do
      import Tartarus.HostCase
      import Tartarus.TestSupport
      alias Tartarus.Test.{Probe, Walker}
    end
  end

  setup do
    hosts_before = Tartarus.hosts()
    agents_before = residents()
    # Registered first, so it runs last (on_exit callbacks run in reverse order).
    on_exit(fn -> assert_no_leaks(hosts_before, agents_before) end)
    :ok
  end

  @doc "A fresh host name (an atom) that no other test uses."
  def unique_name(prefix \\ "h"), do: :"#{prefix}_#{System.unique_integer([:positive])}"

  @doc "The address of a host on this node."
  def addr(name), do: {name, node()}

  @doc "Starts a host with a unique name, stopped when the test ends. Returns its name."
  def host!(opts \\ []) do
    {prefix, opts} = Keyword.pop(opts, :prefix, "h")
    name = unique_name(prefix)
    {:ok, {^name, _}} = Tartarus.start_host(name, opts)
    on_exit(fn -> Tartarus.stop_host(name) end)
    name
  end

  @doc "Starts `n` hosts (not linked)."
  def hosts!(n, opts \\ []), do: for(_ <- 1..n, do: host!(opts))

  @doc "Starts `n` hosts linked in a line: h1 - h2 - ... - hn."
  def line!(n, opts \\ []) do
    hosts = hosts!(n, opts)

    hosts
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.each(fn [a, b] -> :ok = Tartarus.connect(a, b) end)

    hosts
  end

  @doc "Starts `n` hosts linked in a ring."
  def ring!(n, opts \\ []) do
    hosts = line!(n, opts)
    :ok = Tartarus.connect(List.last(hosts), hd(hosts))
    hosts
  end

  @doc """
  Creates a `Tartarus.Test.Probe` (or `module`) agent on `host` whose payload holds the
  calling process under `:test`, so the agent can report to it. Returns the agent's id.
  """
  def agent!(host, args \\ %{}, opts \\ []) do
    {module, opts} = Keyword.pop(opts, :module, Probe)
    opts = Keyword.update(opts, :payload, %{test: self()}, &Map.put_new(&1, :test, self()))
    {:ok, id} = Tartarus.create_agent(host, module, args, opts)
    id
  end

  @doc "The state of a Probe agent."
  def probe_state(ref) do
    {:ok, state} = Tartarus.request(ref, :state)
    state
  end

  @doc "Runs a `Tartarus.Agent` function inside a Probe agent and returns its result."
  def inside(ref, fun, args \\ []) do
    {:ok, result} = Tartarus.request(ref, {:agent, fun, args})
    result
  end

  @doc false
  def assert_no_leaks(hosts_before, agents_before) do
    # Registries drop the entries of dead processes asynchronously: give them a moment (and
    # stop what leaked before failing, so that the next test starts clean).
    wait_for(fn -> Tartarus.hosts() == hosts_before end, 1_000)
    leaked = Tartarus.hosts() -- hosts_before
    Enum.each(leaked, &Tartarus.stop_host/1)
    assert leaked == [], "hosts leaked by the test: #{inspect(leaked)}"

    wait_for(fn -> residents() == agents_before end, 1_000)
    agents = residents()

    assert agents == agents_before,
           "agents leaked by the test: #{inspect(agents -- agents_before)}"
  end

  # The ids of the agents on every host of this node.
  defp residents do
    Tartarus.hosts()
    |> Enum.flat_map(fn h ->
      case Tartarus.agents(h) do
        list when is_list(list) -> Enum.map(list, & &1.id)
        _ -> []
      end
    end)
    |> Enum.sort()
  end
end
