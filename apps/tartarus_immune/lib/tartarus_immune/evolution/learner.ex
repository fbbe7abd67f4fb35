defmodule TartarusImmune.Evolution.Learner do
  @moduledoc """
  A robot node's learner in the sharing experiment (thesis §7.4.3): a static agent that
  evolves a controller for the OR-gate task (`TartarusImmune.Evolution.OrGate`) with the
  (1+1)-online strategy, one evaluation per iteration, and takes in controllers shared by
  its peers.

  It registers itself in its host's store under `:learner`, so agents arriving there find
  it. Requests (all answered):

    * `:iterate` - one evaluation period: propose, evaluate, tell. Answers
      `%{fitness: f, solved: boolean}`;
    * `:share` - broadcasts the champion to the host's neighbours (social learning);
      answers the number of neighbours it went to;
    * `:absorb` - adopts the best controller received by broadcast since the last
      `:absorb` if it beats the champion (the receiver evaluates it itself); answers
      `:adopted` or `:kept`;
    * `{:exchange, weights | nil}` - an iPkt's visit: adopts `weights` if better, answers
      the champion (after adoption) as `{weights, fitness}`;
    * `:status` - `%{fitness:, solved:, received:, adopted:}`.
  """
  use Tartarus.Agent

  alias Tartarus.Agent
  alias TartarusImmune.Evolution.{ES, NeuralNet, OrGate}

  @doc false
  @impl true
  def init(%{seed: seed} = args) do
    rng = :rand.seed_s(:exsss, seed)
    {w, rng} = NeuralNet.random(OrGate.shape(), rng)
    es = ES.new(w, Map.get(args, :es, []))
    es = %{es | fitness: OrGate.fitness(w)}
    Agent.store_put(:learner, Agent.id())
    # Subscribed before create_static_agent returns: a broadcast sent later always finds it.
    :ok = Agent.subscribe_broadcasts()
    {:stay, %{rng: rng, es: es, inbox: [], received: 0, adopted: 0}}
  end

  @doc false
  @impl true
  def handle_message(:iterate, from, s) do
    {kind, w, rng} = ES.propose(s.es, s.rng)
    es = ES.tell(s.es, {kind, w}, OrGate.fitness(w))
    Agent.reply(from, status(es, s))
    {:stay, %{s | es: es, rng: rng}}
  end

  def handle_message(:share, from, s) do
    Agent.reply(from, Agent.broadcast({:controller, s.es.champion}))
    {:stay, s}
  end

  def handle_message(:absorb, from, s) do
    case s.inbox do
      [] ->
        Agent.reply(from, :kept)
        {:stay, s}

      inbox ->
        # The order broadcasts arrived in does not matter: the best one (ties: the
        # smallest weights) is the one considered.
        {f, w} =
          inbox |> Enum.map(&{OrGate.fitness(&1), &1}) |> Enum.min_by(fn {f, w} -> {-f, w} end)

        {result, es} = ES.adopt(s.es, w, f)
        Agent.reply(from, result)

        {:stay,
         %{s | es: es, inbox: [], adopted: s.adopted + if(result == :adopted, do: 1, else: 0)}}
    end
  end

  def handle_message({:exchange, nil}, from, s) do
    Agent.reply(from, {s.es.champion, s.es.fitness})
    {:stay, s}
  end

  def handle_message({:exchange, w}, from, s) do
    {result, es} = ES.adopt(s.es, w, OrGate.fitness(w))
    Agent.reply(from, {es.champion, es.fitness})
    {:stay, %{s | es: es, adopted: s.adopted + if(result == :adopted, do: 1, else: 0)}}
  end

  def handle_message(:status, from, s) do
    Agent.reply(from, status(s.es, s))
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  @impl true
  def handle_info({:tartarus_broadcast, _from, {:controller, w}}, s),
    do: {:stay, %{s | inbox: [w | s.inbox], received: s.received + 1}}

  def handle_info({:tartarus_broadcast, _from, _hello}, s),
    do: {:stay, %{s | received: s.received + 1}}

  def handle_info(_other, s), do: {:stay, s}

  defp status(es, s),
    do: %{
      fitness: es.fitness,
      solved: OrGate.solved?(es.champion),
      received: s.received,
      adopted: s.adopted
    }
end

defmodule TartarusImmune.Evolution.IPkt do
  @moduledoc """
  An intelligent packet (iPkt) of the sharing experiment (thesis §7.4.3): a mobile agent
  that carries the best controller it has met from learner to learner, moving
  conscientiously (`Tartarus.Strategy`).

  On `:visit` (a request from the experiment's driver, once per iteration) it exchanges
  with the learner of the host it is on (`TartarusImmune.Evolution.Learner`: the learner
  adopts the carried controller if it is better, the iPkt takes the learner's if that one
  is better), answers, sends a small `:hello` broadcast (the thesis's neighbour discovery,
  counted like any broadcast) and moves on. It tells the driver (`driver` in its state)
  where it ended up: `{:ipkt_moved, id}` on arrival, `{:ipkt_stayed, id}` when its host had
  no neighbour.
  """
  use Tartarus.Agent,
    ships: [
      TartarusImmune.Evolution.ES,
      TartarusImmune.Evolution.NeuralNet,
      TartarusImmune.Evolution.OrGate,
      TartarusImmune.Evolution.Courier
    ]

  alias Tartarus.Agent
  alias TartarusImmune.Evolution.Courier

  @doc false
  @impl true
  def init(args), do: {:stay, Map.merge(%{weights: nil}, args)}

  @doc false
  @impl true
  def handle_message(:visit, from, s) do
    s =
      case Agent.store_get(:learner) do
        nil ->
          s

        learner ->
          case Tartarus.request(learner, {:exchange, s.weights}) do
            {:ok, {w, _f}} -> %{s | weights: w}
            _ -> s
          end
      end

    Agent.reply(from, :ok)
    Courier.hop(s, hello: true)
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  @impl true
  def handle_arrival(_ctx, s), do: Courier.tell(s, :ipkt_moved)

  @doc false
  @impl true
  def handle_move_failed(_dest, _reason, _ctx, s), do: Courier.tell(s, :ipkt_stayed)
end

defmodule TartarusImmune.Evolution.Courier do
  @moduledoc """
  What the evolution experiments' packets and drivers share: the packets' hop
  (`TartarusImmune.Evolution.IPkt`, `TartarusImmune.Evolution.AbPkt`; called from an
  agent's callbacks, with the agent's state holding the experiment driver's pid under
  `:driver`; the driver waits for one `{:ipkt_moved, id}` or `{:ipkt_stayed, id}` per hop),
  and the drivers' wait for broadcasts to be received (`await_count/4`).
  """

  alias Tartarus.Agent
  alias Tartarus.Clock

  @doc """
  The action that moves the calling agent on to a neighbour it visited least
  (`:conscientious`), after a `:hello` broadcast with `hello: true` (the thesis's neighbour
  discovery, counted like any broadcast); on a host with no neighbour it stays and tells
  the driver so.
  """
  @spec hop(map(), keyword()) :: Tartarus.Agent.action()
  def hop(s, opts \\ []) do
    if Agent.neighbours() == [] do
      tell(s, :ipkt_stayed)
    else
      if opts[:hello], do: Agent.broadcast(:hello)
      {:move, :conscientious, s}
    end
  end

  @doc """
  For the experiments' drivers: polls `count.()` every millisecond (of `Tartarus.Clock`) until it reaches
  `target` (a broadcast is received a moment after the call that sent it returned; waiting
  for it keeps a run independent of the scheduler). Raises, naming `what`, after `tries`
  polls: in these experiments no host stops, so a message that never arrives is an error.
  """
  @spec await_count((() -> non_neg_integer()), non_neg_integer(), non_neg_integer(), String.t()) ::
          :ok
  def await_count(count, target, tries, what) do
    got = count.()

    cond do
      got >= target ->
        :ok

      tries == 0 ->
        raise "#{target - got} of #{target} #{what} not received"

      true ->
        Clock.sleep(1)
        await_count(count, target, tries - 1, what)
    end
  end

  @doc "Tells the driver `{tag, id}` and stays."
  @spec tell(map(), :ipkt_moved | :ipkt_stayed) :: Tartarus.Agent.action()
  def tell(s, tag) do
    send(s.driver, {tag, Agent.id()})
    {:stay, s}
  end
end
