defmodule Tartarus.Examples.Echo do
  @moduledoc """
  A small mobile agent for trying the platform from iex.

  Requests it answers: `:where` (its host), `:hops`, `:payload`, `{:echo, term}`,
  `{:ping, n}` (with `{:pong, n}`). Posts: `{:go, dest}` moves it, `{:tell, to, message}`
  posts `message` to agent `to` (an id or a reference), `:stop` stops it; anything else is
  kept as its state.

      {:ok, id} = Tartarus.create_mobile_agent(:a, Tartarus.Examples.Echo, nil)
      Tartarus.request({id, :a}, :where)
  """
  use Tartarus.Agent

  @impl true
  def init(state), do: {:stay, state}

  @impl true
  def handle_message(:where, from, s), do: reply(from, Tartarus.Agent.host(), s)
  def handle_message(:hops, from, s), do: reply(from, Tartarus.Agent.hops(), s)
  def handle_message(:payload, from, s), do: reply(from, Tartarus.Agent.payload(), s)
  def handle_message(:state, from, s), do: reply(from, s, s)
  def handle_message({:echo, term}, from, s), do: reply(from, term, s)
  def handle_message({:ping, n}, from, s) when from != nil, do: reply(from, {:pong, n}, s)

  def handle_message({:tell, to, message}, _from, s) do
    _ = Tartarus.post(to, message)
    {:stay, s}
  end

  def handle_message({:go, dest}, _from, s), do: {:move, dest, s}
  def handle_message(:stop, _from, s), do: {:stop, :normal, s}
  def handle_message(other, _from, _s), do: {:stay, other}

  defp reply(from, value, s) do
    Tartarus.Agent.reply(from, value)
    {:stay, s}
  end
end
