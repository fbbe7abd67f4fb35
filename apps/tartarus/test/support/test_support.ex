defmodule Tartarus.TestSupport do
  @moduledoc """
  Polling for the tests of every app of the umbrella.

  It is compiled with the platform app in the test environment (`test/support` is in its
  `elixirc_paths`), so every app's tests (each depends on `:tartarus`) and the top-level
  multi-node tests can use it: `import Tartarus.TestSupport`.

  A test that waits for something asynchronous waits for the thing itself: a message
  (`assert_receive`), a reply, or, when nothing tells it, a condition polled with
  `eventually/2`, never a sleep that hopes the other side is done by then.
  """

  @default_timeout 5_000
  @max_interval 25

  @doc """
  Polls `fun` (a zero-arity function) until it returns a truthy value, and returns that
  value. If it never does within `timeout` ms (default #{@default_timeout}), the test fails
  with the condition's code, how long it waited and the last value it returned.

  Polls every millisecond at first, backing off to every #{@max_interval} ms.

      import Tartarus.TestSupport
      eventually(fn -> Tartarus.status(h).resident == 0 end)
      panel = eventually(fn -> List.first(panels(url)) end, 60_000)
  """
  defmacro eventually(fun, timeout \\ @default_timeout) do
    quote do
      Tartarus.TestSupport.eventually!(
        unquote(fun),
        unquote(timeout),
        unquote(Macro.escape(fun))
      )
    end
  end

  @doc false
  # What `eventually/2` expands to: `code` is the quoted condition, for the message.
  @spec eventually!((() -> term()), timeout(), Macro.t()) :: term()
  def eventually!(fun, timeout, code) do
    case wait_for(fun, timeout) do
      {:ok, value} ->
        value

      {:timeout, last} ->
        raise ExUnit.AssertionError,
          message: "condition never held in #{timeout} ms; its last value: #{inspect(last)}",
          expr: code
    end
  end

  @doc """
  Polls `fun` until it returns a truthy value: `{:ok, value}`, or `{:timeout, last}` with
  its last (falsy) value once `timeout` ms pass. It does not fail the test: for callers
  that clean up before they fail, or that expect the condition may not hold.

      iex> Tartarus.TestSupport.wait_for(fn -> :done end, 10)
      {:ok, :done}
      iex> Tartarus.TestSupport.wait_for(fn -> nil end, 10)
      {:timeout, nil}
  """
  @spec wait_for((() -> term()), timeout()) :: {:ok, term()} | {:timeout, term()}
  def wait_for(fun, timeout \\ @default_timeout) when is_function(fun, 0) do
    deadline =
      if timeout == :infinity, do: :infinity, else: System.monotonic_time(:millisecond) + timeout

    poll(fun, deadline, 1)
  end

  defp poll(fun, deadline, interval) do
    value = fun.()

    cond do
      value ->
        {:ok, value}

      deadline != :infinity and System.monotonic_time(:millisecond) >= deadline ->
        {:timeout, value}

      true ->
        Process.sleep(interval)
        poll(fun, deadline, min(interval * 2, @max_interval))
    end
  end
end
