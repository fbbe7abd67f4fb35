defmodule Tartarus.Plugin.Shorthand do
  @moduledoc """
  Plugin specs as configuration files and command lines write them, turned into
  `{module, opts}` by one function, `parse/3`, which the release's configuration check
  (the node app's) and `mix tartarus.node` both call.

    * `{module, opts}`: a plugin module (it must be in this node's code and define `init/1`;
      if it defines `check/1`, the options are checked there, without touching a device:
      `Tartarus.Plugin.GPIO` refuses pins with no GPIO backend this way);
    * `{:sensor, opts}`: `Tartarus.Plugin.SimSensor` (a sine-like signal unless `signal:`);
    * `{:serial, device}` / `{:serial, device, opts}`: `Tartarus.Plugin.Serial` (9600 baud
      unless `speed:`), read as text lines;
    * `{:ble, device}` / `{:ble, device, opts}`: the BLE receiver of this node (below).

  Options are keyword lists in every form, a sensor's `signal:` a non-empty list of numbers
  (`unit:` a string, `interval_ms:` a positive integer), and whatever the form, the plugin
  module's `check/1`, when it defines one, checks the options it would start with (the
  serial line's `Tartarus.Plugin.Serial.check/1`: speed, decoder, transport): a bad value is
  refused here, not when the node boots.

  ## The BLE receiver

  The platform names no application, so an application that brings a BLE receiver says so
  in its application environment (its `mix.exs`), as LATS does:

      def application, do: [env: [tartarus_ble_plugin: {MyApp.Receiver, :plugin}]]

  (LATS's device app, `apps/tartarus_lats_device`, says so for its HM-10 receiver.)

  `function(device, opts)` returns the plugin spec. `ble_receiver/0` finds it in the
  applications on the code path, loaded or not (`Tartarus.Provides`), so the answer is the
  same in a running node, in `mix`, and in the short VM that checks a release's
  configuration before the node boots (started without the release's `sys.config`, where an
  application environment set by `config/*.exs` would not be seen).

  ## Devices that are not there

  With `devices: :present` (the release's check), a `:serial` or `:ble` device path that
  does not exist is an error, unless the spec's options say `hotplug: true` (a USB adapter
  plugged in later: the plugin opens the device when it appears). With `devices: :any` (the
  default; `mix tartarus.node` warns instead) any path is taken.

  Errors are one line naming the plugin and the cause:

      iex> Tartarus.Plugin.Shorthand.parse(:x, {:nope, 1})
      {:error, "x: expected {module, opts}, {:sensor, opts}, {:serial, device} or {:ble, device}, got: {:nope, 1}"}
      iex> Tartarus.Plugin.Shorthand.parse(:b, {:ble, "/dev/ttyUSB0"}, ble_receiver: :none)
      {:error, "b: {:ble, ...} needs a BLE receiver, and no application of this node provides one (an application's env :tartarus_ble_plugin, as LATS's; a release built with TARTARUS_RELEASE_LATS=false has none)"}
  """

  @app_key :tartarus_ble_plugin

  @typedoc "A plugin spec as `Tartarus.attach_plugin/3` takes it."
  @type spec :: {module(), keyword()}

  @doc """
  Turns the spec of plugin `name` into `{module, opts}`, or `{:error, line}`.

  Options: `devices: :any | :present` (see the moduledoc), `ble_receiver:` (`{module,
  function}` or `:none`, instead of `ble_receiver/0`'s answer: for tests).

      iex> Tartarus.Plugin.Shorthand.parse(:tty, {:serial, "/dev/ttyS1", speed: 115_200})
      {:ok, {Tartarus.Plugin.Serial, [speed: 115_200, device: "/dev/ttyS1"]}}
      iex> {:ok, {Tartarus.Plugin.SimSensor, opts}} = Tartarus.Plugin.Shorthand.parse(:t, {:sensor, signal: [1.0]})
      iex> opts
      [signal: [1.0], unit: "°C"]
  """
  @spec parse(atom(), term(), keyword()) :: {:ok, spec()} | {:error, String.t()}
  def parse(name, spec, opts \\ []) do
    with :ok <- keyword_options(spec),
         {:ok, {module, plugin_opts}} = ok <- do_parse(name, spec, opts),
         :ok <- module_check(module, plugin_opts) do
      ok
    else
      {:error, what} -> {:error, "#{name}: #{what}"}
    end
  end

  # Every form's options are a keyword list (Keyword's functions raise on any other list).
  defp keyword_options(spec) do
    options =
      case spec do
        {kind, _device, o} when kind in [:serial, :ble] -> o
        {module, o} when is_atom(module) and module not in [:serial, :ble] -> o
        _ -> []
      end

    if not is_list(options) or Keyword.keyword?(options),
      do: :ok,
      else: {:error, "options: expected a keyword list, got: #{inspect(options, limit: 8)}"}
  end

  defp do_parse(_name, {:sensor, opts}, _) when is_list(opts) do
    signal = Keyword.get(opts, :signal, Enum.map(0..59, &(20 + :math.sin(&1 / 10) * 5)))

    cond do
      not (is_list(signal) and signal != [] and Enum.all?(signal, &is_number/1)) ->
        {:error,
         "signal: expected a non-empty list of numbers, got: #{inspect(signal, limit: 8)}"}

      not is_binary(Keyword.get(opts, :unit, "")) ->
        {:error, "unit: expected a string, got: #{inspect(opts[:unit], limit: 8)}"}

      not (is_nil(opts[:interval_ms]) or
               (is_integer(opts[:interval_ms]) and opts[:interval_ms] > 0)) ->
        {:error,
         "interval_ms: expected a positive integer, got: #{inspect(opts[:interval_ms], limit: 8)}"}

      true ->
        {:ok,
         {Tartarus.Plugin.SimSensor,
          [unit: "°C"] |> Keyword.merge(opts) |> Keyword.put(:signal, signal)}}
    end
  end

  defp do_parse(name, {kind, device}, opts) when kind in [:serial, :ble],
    do: do_parse(name, {kind, device, []}, opts)

  defp do_parse(_name, {:serial, device, dev_opts}, opts)
       when is_binary(device) and is_list(dev_opts) do
    with {:ok, dev_opts} <- device_present(device, dev_opts, opts) do
      {:ok, {Tartarus.Plugin.Serial, Keyword.merge([speed: 9600], dev_opts) ++ [device: device]}}
    end
  end

  defp do_parse(_name, {:ble, device, dev_opts}, opts)
       when is_binary(device) and is_list(dev_opts) do
    with {:ok, dev_opts} <- device_present(device, dev_opts, opts),
         {:ok, {m, f}} <- receiver(Keyword.get_lazy(opts, :ble_receiver, &ble_receiver/0)) do
      case apply(m, f, [device, Keyword.merge([speed: 9600], dev_opts)]) do
        {module, plugin_opts} = spec when is_atom(module) and is_list(plugin_opts) ->
          {:ok, spec}

        other ->
          {:error,
           "the BLE receiver #{inspect(m)}.#{f}/2 returned #{inspect(other)}, not {module, opts}"}
      end
    end
  end

  defp do_parse(_name, {module, plugin_opts}, _opts)
       when is_atom(module) and is_list(plugin_opts) do
    if Code.ensure_loaded?(module) and function_exported?(module, :init, 1),
      do: {:ok, {module, plugin_opts}},
      else: {:error, "#{inspect(module)} is not a plugin module in this node's code"}
  end

  defp do_parse(_name, other, _opts),
    do:
      {:error,
       "expected {module, opts}, {:sensor, opts}, {:serial, device} or {:ble, device}, got: #{inspect(other)}"}

  # A plugin module that defines check/1 checks its options there, without a device.
  defp module_check(module, plugin_opts) do
    if Code.ensure_loaded?(module) and function_exported?(module, :check, 1) do
      case module.check(plugin_opts) do
        :ok -> :ok
        {:error, reason} when is_binary(reason) -> {:error, reason}
        other -> {:error, inspect(other, limit: 8)}
      end
    else
      :ok
    end
  end

  defp device_present(device, dev_opts, opts) do
    {hotplug, dev_opts} = Keyword.pop(dev_opts, :hotplug, false)

    if Keyword.get(opts, :devices, :any) == :present and hotplug != true and
         not File.exists?(device),
       do:
         {:error,
          "no such device #{device} (plug it in, or say hotplug: true to open it when it appears)"},
       else: {:ok, dev_opts}
  end

  defp receiver(:none),
    do:
      {:error,
       "{:ble, ...} needs a BLE receiver, and no application of this node provides one " <>
         "(an application's env :#{@app_key}, as LATS's; a release built with " <>
         "TARTARUS_RELEASE_LATS=false has none)"}

  defp receiver({:error, why}), do: {:error, "{:ble, ...} needs a BLE receiver: #{why}"}
  defp receiver({:ok, mf}), do: receiver(mf)

  defp receiver({m, f}) when is_atom(m) and is_atom(f) do
    if Code.ensure_loaded?(m) and function_exported?(m, f, 2),
      do: {:ok, {m, f}},
      else: {:error, "the BLE receiver #{inspect(m)}.#{f}/2 is not in this node's code"}
  end

  defp receiver(other),
    do: {:error, "a BLE receiver is {module, function}, got: #{inspect(other)}"}

  @doc """
  The BLE receiver this node's applications provide: `{:ok, {module, function}}` from the
  first application on the code path (by name) whose environment has `:tartarus_ble_plugin`,
  `:none` if none has, `{:error, why}` if the value is not `{module, function}`.
  """
  @spec ble_receiver() :: {:ok, {module(), atom()}} | :none | {:error, String.t()}
  def ble_receiver do
    case Tartarus.Provides.find(@app_key) do
      [] ->
        :none

      [{_app, {m, f}} | _] when is_atom(m) and is_atom(f) ->
        {:ok, {m, f}}

      [{app, other} | _] ->
        {:error, "application #{app}'s :#{@app_key} is not {module, function}: #{inspect(other)}"}
    end
  end
end
