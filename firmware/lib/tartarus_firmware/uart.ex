defmodule TartarusFirmware.UART do
  @moduledoc """
  A `Tartarus.Plugin.Serial.Transport` over `Circuits.UART` (the Pi's UARTs, USB serial
  adapters), so `Tartarus.Plugin.Serial` and its decoders run on the Pi as they do on a
  laptop's tty.

  The UART runs in active mode: its bytes arrive as `{:circuits_uart, name, data}`, an error
  (the adapter unplugged) as `{:circuits_uart, name, {:error, reason}}`, which closes the
  connection; the serial plugin then reopens it with backoff. Devices are named as
  `Circuits.UART` names them (`"ttyAMA0"`; a leading `/dev/` is dropped).
  """
  @behaviour Tartarus.Plugin.Serial.Transport

  @impl true
  def open(device, opts) do
    name = String.replace_prefix(device, "/dev/", "")
    speed = Keyword.get(opts, :speed, 9600)
    {:ok, pid} = Circuits.UART.start_link()

    case Circuits.UART.open(pid, name, speed: speed, active: true) do
      :ok ->
        send(self(), {__MODULE__, pid, :opened})
        {:ok, %{pid: pid, name: name}}

      {:error, reason} ->
        Circuits.UART.stop(pid)
        {:error, reason}
    end
  end

  @impl true
  def write(%{pid: pid}, data), do: Circuits.UART.write(pid, data)

  @impl true
  def close(%{pid: pid}) do
    _ = Circuits.UART.close(pid)
    Circuits.UART.stop(pid)
  end

  @impl true
  def message({__MODULE__, pid, :opened}, %{pid: pid} = t), do: {[:opened], t}

  def message({:circuits_uart, name, {:error, reason}}, %{name: name} = t) do
    close(t)
    {[{:closed, reason}], t}
  end

  def message({:circuits_uart, name, data}, %{name: name} = t) when is_binary(data),
    do: {[{:data, data}], t}

  def message(_msg, _t), do: :ignore
end
