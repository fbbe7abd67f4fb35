# Test doubles of Circuits.UART (1.5) and Circuits.GPIO (2.x), for the firmware's adapters
# (test/firmware_test.exs). They have the real modules' functions, names and arities, the
# message shapes the real ones send, and a small control API (Circuits.*.Double) with which
# a test plugs and unplugs devices and drives pins. They live only in the test suite: the
# firmware itself depends on the real packages from hex.

defmodule Circuits.UART.Double do
  @moduledoc false
  # The serial devices that exist: name => %{present: bool, owner: pid | nil, written: binary}.
  use Agent

  def start_link(_ \\ []), do: Agent.start_link(fn -> %{} end, name: __MODULE__)

  def plug(name),
    do: Agent.update(__MODULE__, &Map.put(&1, name, %{present: true, owner: nil, written: ""}))

  # The device disappears; its owner, if any, gets the error a real UART reports.
  def unplug(name) do
    owner =
      Agent.get_and_update(__MODULE__, fn m ->
        {get_in(m, [name, :owner]), Map.delete(m, name)}
      end)

    if owner, do: send(owner, {:circuits_uart, name, {:error, :eio}})
    :ok
  end

  # Bytes arriving from the device, in active mode.
  def inject(name, data) do
    case Agent.get(__MODULE__, &get_in(&1, [name, :owner])) do
      nil -> {:error, :not_open}
      owner -> send(owner, {:circuits_uart, name, data}) && :ok
    end
  end

  def written(name), do: Agent.get(__MODULE__, &get_in(&1, [name, :written]))

  def update(name, fun),
    do:
      Agent.get_and_update(__MODULE__, fn m ->
        case m do
          %{^name => d} -> {:ok, Map.put(m, name, fun.(d))}
          _ -> {{:error, :enoent}, m}
        end
      end)
end

defmodule Circuits.UART do
  @moduledoc false
  # Each UART is a process holding the name of the device it opened.

  def start_link(genserver_opts \\ []) when is_list(genserver_opts),
    do: Agent.start_link(fn -> nil end)

  def open(pid, name, opts \\ []) when is_binary(name) and is_list(opts) do
    owner = self()

    with :ok <- Circuits.UART.Double.update(name, &%{&1 | owner: owner}) do
      Agent.update(pid, fn _ -> name end)
    end
  end

  def write(pid, data, timeout \\ 5000) when is_integer(timeout) do
    case Agent.get(pid, & &1) do
      nil ->
        {:error, :ebadf}

      name ->
        Circuits.UART.Double.update(
          name,
          &%{&1 | written: &1.written <> IO.iodata_to_binary(data)}
        )
    end
  end

  def close(pid) do
    case Agent.get_and_update(pid, &{&1, nil}) do
      nil -> :ok
      name -> _ = Circuits.UART.Double.update(name, &%{&1 | owner: nil}) && :ok
    end
  end

  def stop(pid), do: Agent.stop(pid)
end

defmodule Circuits.GPIO.Double do
  @moduledoc false
  # Pin levels and who asked for interrupts: line => %{level: 0 | 1, watcher: pid | nil}.
  use Agent

  def start_link(_ \\ []), do: Agent.start_link(fn -> %{} end, name: __MODULE__)

  def level(line), do: Agent.get(__MODULE__, &get_in(&1, [line, :level]))

  # The outside world drives an input; a watcher gets the interrupt message on a change.
  def drive(line, level) do
    {old, watcher} =
      Agent.get_and_update(__MODULE__, fn m ->
        pin = Map.get(m, line, %{level: 0, watcher: nil})
        {{pin.level, pin.watcher}, Map.put(m, line, %{pin | level: level})}
      end)

    if watcher && old != level,
      do: send(watcher, {:circuits_gpio, line, System.monotonic_time(), level})

    :ok
  end

  def put(line, fun),
    do:
      Agent.update(__MODULE__, fn m ->
        Map.put(m, line, fun.(Map.get(m, line, %{level: 0, watcher: nil})))
      end)
end

defmodule Circuits.GPIO do
  @moduledoc false

  def open(gpio_spec, direction, options \\ []) when direction in [:input, :output] do
    if direction == :output,
      do:
        Circuits.GPIO.Double.put(
          gpio_spec,
          &%{&1 | level: Keyword.get(options, :initial_value, 0)}
        )

    {:ok, %{line: gpio_spec, direction: direction}}
  end

  def read(%{line: line}), do: Circuits.GPIO.Double.level(line) || 0

  def write(%{line: line, direction: :output}, value) when value in [0, 1],
    do: Circuits.GPIO.Double.put(line, &%{&1 | level: value})

  def set_interrupts(%{line: line}, trigger, options \\ [])
      when trigger in [:none, :rising, :falling, :both] and is_list(options) do
    watcher = if trigger == :none, do: nil, else: self()
    Circuits.GPIO.Double.put(line, &%{&1 | watcher: watcher})
  end

  def close(_gpio), do: :ok
end
