defmodule Tartarus.Host.ArrivalDoor do
  @moduledoc false
  # The node's door for arriving agents, registered as `:tartarus_arrivals`: a source on
  # another node sends its prepare here (`{:"$tartarus_arrive", dest, prepare}`, one
  # distribution message) and the door spawns the prepare's admission on this node
  # (Tartarus.Host.Arrivals.admit/2), which checks it, becomes the paused copy and answers
  # the source itself. The door does nothing else: no check, no table, one local spawn a
  # prepare, so arrivals do not queue behind any host's server.
  #
  # Why a door rather than the source spawning the admission over distribution
  # (:erlang.spawn_request/5): a distributed spawn request is answered by a spawn reply over
  # the connection whatever its reply option says (measured: 1,007 packets back for 1,000
  # requests with `reply: :no`), which made a hop four distribution messages, not three.
  # This is the shape of the migration benchmark's floor (its receiver process).
  #
  # Anything else it receives (junk from any node) is dropped and counted
  # (Tartarus.Events.drop/3). A prepare sent while the door restarts is lost, as any message
  # can be: the source's hand-off times out and its agent stays where it was.
  use GenServer
  require Tartarus.Events

  @name :tartarus_arrivals

  @doc false
  def start_link(_opts), do: GenServer.start_link(__MODULE__, nil, name: @name)

  @impl true
  def init(nil) do
    # As the admissions it spawns: a prepare is passed on ahead of runnable agents.
    Process.flag(:priority, :high)
    {:ok, nil}
  end

  @impl true
  def handle_info({:"$tartarus_arrive", dest, prepare}, state) do
    Tartarus.Host.Arrivals.admit_spawn(dest, prepare)
    {:noreply, state}
  end

  def handle_info(other, state) do
    Tartarus.Events.drop(@name, :info, other)
    {:noreply, state}
  end

  @impl true
  def handle_call(msg, from, state) when not Tartarus.Events.is_from(from) do
    Tartarus.Events.drop(@name, :call, msg)
    {:noreply, state}
  end

  def handle_call(msg, from, state) do
    Tartarus.Events.drop(@name, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, state}
  end

  @impl true
  def handle_cast(msg, state) do
    Tartarus.Events.drop(@name, :cast, msg)
    {:noreply, state}
  end
end
