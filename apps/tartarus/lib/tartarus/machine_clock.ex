defmodule Tartarus.MachineClock do
  @moduledoc """
  `receive` whose `after` clause waits on the machine's time, in either mode of
  `Tartarus.Clock`: for a wait on the apparatus rather than on the design (an HTTP
  connection, a browser or a peer node's operating-system process starting or going, a
  setup step's safety net). Its timer is `Tartarus.Clock.machine_send_after/3`, so a
  virtual clock neither waits for it nor jumps past it. A wait the design makes (for agents,
  a protocol's timeout) is `Tartarus.Clock.receive/1`.

      require Tartarus.MachineClock

      Tartarus.MachineClock.receive do
        {:nodedown, ^node} -> :ok
      after
        10_000 -> :timeout
      end

  The clauses are the same as `Kernel.SpecialForms.receive/1`'s; `after 0` checks the
  mailbox as it is, `after :infinity` waits for ever.
  """

  @doc """
  `receive` whose `after` clause is a timer of the machine's time (see the moduledoc).
  Without an `after` clause it is the plain `receive`.
  """
  defmacro receive(blocks) do
    clauses = Keyword.get(blocks, :do, [])

    case Keyword.get(blocks, :after) do
      nil ->
        quote do: receive(do: unquote(clauses))

      [{:->, _, [[timeout], after_body]}] ->
        timer = Macro.var(:machine_timer, __MODULE__)
        tag = Macro.var(:machine_tag, __MODULE__)

        wrapped = Tartarus.Clock.__wrap__(clauses, Tartarus.MachineClock, timer, tag)

        # First, so that a catch-all clause of the caller never takes the timeout's message.
        timeout_clause =
          quote do
            {:"$tartarus_machine_clock_after", ^unquote(tag)} -> unquote(after_body)
          end

        quote do
          {unquote(timer), unquote(tag)} = Tartarus.MachineClock.__after__(unquote(timeout))

          receive do
            unquote(timeout_clause ++ wrapped)
          end
        end

      _ ->
        raise ArgumentError, "Tartarus.MachineClock.receive: expected one `after` clause"
    end
  end

  @doc false
  # For receive/1: {timer, tag}. `after :infinity` arms nothing (the tag matches no message);
  # `after 0` sends the timeout's message at once, behind what is in the mailbox already.
  def __after__(:infinity), do: {nil, make_ref()}

  def __after__(0) do
    tag = make_ref()
    send(self(), {:"$tartarus_machine_clock_after", tag})
    {:sent, tag}
  end

  def __after__(ms) when is_integer(ms) and ms > 0 do
    tag = make_ref()
    {Tartarus.Clock.machine_send_after(self(), {:"$tartarus_machine_clock_after", tag}, ms), tag}
  end

  def __after__(t),
    do: raise(ArgumentError, "receive's after expects a timeout, got: #{inspect(t)}")

  @doc false
  # A clause other than the timeout matched: the timer goes, and its message if it came.
  def __done__(nil, _tag), do: :ok
  def __done__(:sent, tag), do: flush(tag)

  def __done__(timer, tag) do
    if Tartarus.Clock.cancel_timer(timer) == false, do: flush(tag)
    :ok
  end

  defp flush(tag) do
    receive do
      {:"$tartarus_machine_clock_after", ^tag} -> :ok
    after
      0 -> :ok
    end
  end
end
