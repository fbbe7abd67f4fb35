defmodule TartarusWarehouse.Rack do
  @moduledoc """
  The static agent of a shared-resource node (Φ, thesis §4.7.1: "a static agent residing
  on each of the R- and Φ-type nodes performed the job of waiting for the mobile agents in
  order to receive the code for the task to be performed within them"). A floor started
  with `phi_agents: true` (`TartarusWarehouse.Floor.Options`) runs one on each Φ node
  (`f1`, `f2`, ...), and a task agent that has claimed its robot hands the rack of each of
  its block's resources the code of the tasks that use it, and waits for the rack's
  answer, before the robot runs the block (`TartarusWarehouse.TaskAgent`). The code travels
  as a request between the two hosts: in an emulated floor it pays the latencies of its
  route both ways, as every message between hosts does.

  Which rack holds a resource: `rack_for/2`. What a rack received: the request
  `:received`, answered with the list of `{agent, task, program}` in the order they came.

  It checks that the program is code it can load (`Code.ensure_loaded/1`) and answers
  `:ok`, or `{:error, {:no_code, program}}`; it runs nothing itself (the thesis's Φ nodes
  only receive the code in the emulation; what a rack would do with it is the
  application's).
  """
  use Tartarus.Agent

  @doc """
  The rack, of `racks` (a non-empty list, `f1` first), that holds `resource`: `{:psi, i}`
  is on rack `(i - 1) rem length(racks)` (ψ1 on f1, ψ21 on f1 again with 20 racks); any
  other resource on the rack its hash picks.

      iex> TartarusWarehouse.Rack.rack_for({:psi, 1}, [:f1, :f2, :f3])
      :f1
      iex> TartarusWarehouse.Rack.rack_for({:psi, 5}, [:f1, :f2, :f3])
      :f2
  """
  @spec rack_for(term(), [rack]) :: rack when rack: term()
  def rack_for({:psi, i}, racks) when is_integer(i) and i > 0,
    do: Enum.at(racks, rem(i - 1, length(racks)))

  def rack_for(resource, racks), do: Enum.at(racks, :erlang.phash2(resource, length(racks)))

  @doc false
  @impl true
  def init(args), do: {:stay, %{rack: args.rack, received: []}}

  @doc false
  @impl true
  def handle_message({:code, agent, tasks}, from, s) when from != nil do
    case Enum.find(tasks, fn {_task, program} -> not loadable?(program) end) do
      nil ->
        Tartarus.Agent.reply(from, :ok)
        # Newest first here; `:received` answers oldest first.
        new = for {task, program} <- Enum.reverse(tasks), do: {agent, task, program}
        {:stay, %{s | received: new ++ s.received}}

      {_task, program} ->
        Tartarus.Agent.reply(from, {:error, {:no_code, program}})
        {:stay, s}
    end
  end

  def handle_message(:received, from, s) when from != nil do
    Tartarus.Agent.reply(from, Enum.reverse(s.received))
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  defp loadable?(program),
    do: is_atom(program) and match?({:module, _}, Code.ensure_loaded(program))
end
