defmodule Tartarus.Plugin.Serial.Tty do
  @moduledoc """
  A `Tartarus.Plugin.Serial.Transport` for any tty of a plain Linux host (`/dev/ttyUSB0`,
  `/dev/ttyAMA0`, a pseudo-terminal), with nothing but OTP and the system's `sh`, `stty`
  and `cat`: no NIF, no hex package.

  Opening spawns an Erlang port running a small shell script that

    1. opens the device read-write (refusing anything that is not a character device:
       exit status 2),
    2. puts it in raw mode at the requested speed with `stty` (`raw -echo clocal cread`;
       exit status 3 if the device refuses),
    3. prints a marker line, so the plugin knows the device is really open and configured,
    4. runs `cat` from the device to the port (the bytes as they come, in whatever chunks the
       tty gives) and another `cat` from the port to the device (what the plugin writes).

  When the device disappears (a USB adapter unplugged, the other end of a pseudo-terminal
  closed) the reading `cat` ends on the hang-up and the script exits: the port's exit
  status is the `{:closed, {:exit_status, n}}` item. When the plugin closes the port, the
  writing `cat` sees the end of its input and stops the reading one, so no process keeps
  reading the device after the port is gone. Nothing is ever created at the device's path.

  Options: `:speed` (baud, default 9600).
  """
  @behaviour Tartarus.Plugin.Serial.Transport

  @marker "tartarus-serial-open\n"

  @script """
  exec 2>/dev/null
  exec 5<"$1" || exit 2
  [ -c /dev/fd/5 ] || exit 2
  exec 4<>/dev/fd/5 || exit 2
  exec 5<&-
  stty "$2" raw -echo clocal cread <&4 || exit 3
  exec 3<&0
  printf '#{String.trim_trailing(@marker)}\\n'
  cat <&4 &
  r=$!
  { cat <&3 >&4; kill "$r"; } &
  w=$!
  wait "$r"
  s=$?
  kill "$w"
  exit "$s"
  """

  @impl true
  def open(device, opts) when is_binary(device) do
    speed = Keyword.get(opts, :speed, 9600)

    with {:ok, %File.Stat{type: :device}} <- File.stat(device),
         sh when is_binary(sh) <- System.find_executable("sh") || {:error, :no_sh} do
      port =
        Port.open({:spawn_executable, sh}, [
          :binary,
          :exit_status,
          :use_stdio,
          args: ["-c", @script, "tartarus-serial", device, Integer.to_string(speed)]
        ])

      {:ok, %{port: port, opening: <<>>}}
    else
      {:ok, %File.Stat{type: type}} -> {:error, {:not_a_device, type}}
      {:error, reason} -> {:error, reason}
    end
  end

  @impl true
  def write(%{port: port, opening: nil}, data) do
    # A device that stops reading must not block the plugin: what the port cannot take now
    # is refused, not queued.
    if :erlang.port_command(port, data, [:nosuspend]), do: :ok, else: {:error, :busy}
  rescue
    ArgumentError -> {:error, :closed}
  end

  def write(_t, _data), do: {:error, :not_open}

  @impl true
  def close(%{port: port}) do
    Port.close(port)
    :ok
  rescue
    ArgumentError -> :ok
  end

  @impl true
  def message({port, {:data, data}}, %{port: port, opening: nil} = t), do: {[{:data, data}], t}

  def message({port, {:data, data}}, %{port: port, opening: buf} = t) do
    buf = buf <> data
    size = byte_size(@marker)

    case buf do
      <<@marker, rest::binary>> ->
        items = if rest == <<>>, do: [:opened], else: [:opened, {:data, rest}]
        {items, %{t | opening: nil}}

      _ when byte_size(buf) < size ->
        {[], %{t | opening: buf}}

      _ ->
        close(t)
        {[{:closed, {:unexpected_output, buf}}], t}
    end
  end

  def message({port, {:exit_status, status}}, %{port: port} = t),
    do: {[{:closed, reason(status)}], t}

  def message(_msg, _t), do: :ignore

  defp reason(2), do: :no_device
  defp reason(3), do: :stty_failed
  defp reason(status), do: {:exit_status, status}
end
