defmodule Tartarus.Agent.StateTimer do
  @moduledoc false
  # The state timeouts of the agent's state machine (Tartarus.Agent.Server) as timers of
  # Tartarus.Clock, with gen_statem's semantics: one at a time, armed for a state, cancelled
  # by leaving it; the server acts on `{:timeout, timer, {:"$tartarus_state_timeout", what}}`
  # only while the timer and the state are still the ones armed. Its own module, so that
  # the server, its actions and the arrival's executor arm it without depending on each
  # other.
  alias Tartarus.Clock

  @timeout :"$tartarus_state_timeout"

  # Arms the state timeout of `state` (the state this process is in, or enters with `data`):
  # `ms` ms of Tartarus.Clock, then its event (`:handoff` in :handing_off, `:commit` in
  # :paused and :awaiting_commit). Replaces the one armed before, as gen_statem's would.
  @spec arm(map(), :handing_off | :paused | :awaiting_commit, timeout()) :: map()
  def arm(data, state, ms) do
    data = cancel(data)

    case ms do
      :infinity ->
        data

      ms ->
        what = if state == :handing_off, do: :handoff, else: :commit
        %{data | timer: {Clock.start_timer(ms, self(), {@timeout, what}), state}}
    end
  end

  # Cancels the state timeout armed (leaving its state). A message it already sent is
  # stale now and ignored when it comes.
  @spec cancel(map()) :: map()
  def cancel(%{timer: nil} = data), do: data

  def cancel(%{timer: {t, _state}} = data) do
    Clock.cancel_timer(t)
    %{data | timer: nil}
  end
end
