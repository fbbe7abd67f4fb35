defmodule Tartarus.Plugin.GPIO do
  @pin_expected "a keyword list of name: {line, :input | :output} or {line, :output, 0 | 1}"
  @schema [
    pins: [
      type: {:custom, &__MODULE__.pins?/1},
      required: true,
      expected: @pin_expected,
      doc: "the pins, by name: `{line, :input}`, `{line, :output}` or `{line, :output, initial}`"
    ],
    backend: [
      type: :atom,
      doc:
        "a `Tartarus.Plugin.GPIO.Backend` (the firmware's wraps `Circuits.GPIO`; `Tartarus.Plugin.GPIO.Sim` simulates); default: `config :tartarus, :gpio_backend`, else `Tartarus.Plugin.GPIO.Nil`, which has no pins"
    ]
  ]
  @moduledoc """
  GPIO pins as a `Tartarus.Plugin`: named inputs (buttons, bump switches, end stops) and
  outputs (LEDs, relays, a claw's servo enable), real in the firmware and simulated where
  asked, with the same contract, because only the backend (`Tartarus.Plugin.GPIO.Backend`)
  differs.

      Tartarus.attach_plugin(:claus, :claws,
        {Tartarus.Plugin.GPIO, pins: [grip: {17, :output}, closed: {27, :input}],
         backend: Tartarus.Plugin.GPIO.Sim, capabilities: [:claws]})

  The backend is chosen explicitly, as `Circuits.GPIO` chooses its own: the `backend:`
  option, else the application environment (`config :tartarus, :gpio_backend, module`),
  else `Tartarus.Plugin.GPIO.Nil`, which answers `{:error, :no_gpio_backend}`: a node
  without GPIO hardware refuses the plugin (`init/1` fails with `{:gpio_open_failed, pin,
  line, :no_gpio_backend}`; `check/1` says it in one line before any pin is touched) rather
  than simulate pins it was told are real.

  Reads: `{:pin, name}` (`0` or `1`), `:all` or `nil` (`%{name => level}`). Writes:
  `{:pin, name, level}` sets an output (`{:error, {:not_an_output, name}}` for an input).
  Subscribers get `{:edge, name, level}` when an input changes. The simulated backend also
  takes `{:stimulate, name, level}`, which drives an input as the outside world would (the
  firmware's backend refuses it as a bad argument: real inputs are driven by the world).
  An unknown pin is `{:error, {:no_such_pin, name}}`; any other argument
  `{:error, {:bad_argument, arg}}`.

  Options:

  #{Tartarus.Options.docs(@schema)}
  """
  @behaviour Tartarus.Plugin

  @doc false
  def pins?([_ | _] = pins) do
    Keyword.keyword?(pins) and length(Enum.uniq(Keyword.keys(pins))) == length(pins) and
      Enum.all?(pins, fn
        {_name, {_line, :input}} -> true
        {_name, {_line, :output}} -> true
        {_name, {_line, :output, initial}} -> initial in [0, 1]
        _ -> false
      end)
  end

  def pins?(_), do: false

  @impl true
  def init(opts) do
    with {:ok, o} <- Tartarus.Options.validate(opts, @schema, "Tartarus.Plugin.GPIO"),
         backend = backend(o),
         :ok <- backend?(backend) do
      open_all(o[:pins], backend)
    end
  end

  @doc """
  Checks `opts` without opening any pin (what a node's configuration check calls, see
  `Tartarus.Plugin.Shorthand`): the options, and that the backend is a real one, in one
  line otherwise.

      iex> Tartarus.Plugin.GPIO.check(pins: [led: {17, :output}], backend: Tartarus.Plugin.GPIO.Nil)
      {:error, "Tartarus.Plugin.GPIO: no GPIO backend on this node for pins led (line 17) (Tartarus.Plugin.GPIO.Nil answers {:error, :no_gpio_backend}): name one with backend: (the firmware's wraps Circuits.GPIO; Tartarus.Plugin.GPIO.Sim simulates pins)"}
      iex> Tartarus.Plugin.GPIO.check(pins: [led: {17, :output}], backend: Tartarus.Plugin.GPIO.Sim)
      :ok
  """
  @spec check(keyword()) :: :ok | {:error, String.t()}
  def check(opts) do
    with {:ok, o} <- Tartarus.Options.validate(opts, @schema, "Tartarus.Plugin.GPIO"),
         backend = backend(o),
         :ok <- backend?(backend) do
      if backend == Tartarus.Plugin.GPIO.Nil do
        pins =
          Enum.map_join(o[:pins], ", ", fn {name, spec} -> "#{name} (line #{elem(spec, 0)})" end)

        {:error,
         "Tartarus.Plugin.GPIO: no GPIO backend on this node for pins #{pins} " <>
           "(Tartarus.Plugin.GPIO.Nil answers {:error, :no_gpio_backend}): name one with " <>
           "backend: (the firmware's wraps Circuits.GPIO; Tartarus.Plugin.GPIO.Sim simulates pins)"}
      else
        :ok
      end
    end
  end

  defp backend(o),
    do: o[:backend] || Application.get_env(:tartarus, :gpio_backend, Tartarus.Plugin.GPIO.Nil)

  defp backend?(module) do
    callbacks = Tartarus.Plugin.GPIO.Backend.behaviour_info(:callbacks)

    if Code.ensure_loaded?(module) and
         Enum.all?(callbacks, fn {f, a} -> function_exported?(module, f, a) end) do
      :ok
    else
      {:error,
       "invalid options given to Tartarus.Plugin.GPIO for key :backend: expected a module implementing Tartarus.Plugin.GPIO.Backend, got: #{inspect(module)}"}
    end
  end

  defp open_all(pins, backend) do
    Enum.reduce_while(pins, {:ok, %{backend: backend, pins: %{}, lines: %{}}}, fn
      {name, spec}, {:ok, s} ->
        {line, direction, initial} =
          case spec do
            {line, dir} -> {line, dir, 0}
            {line, :output, initial} -> {line, :output, initial}
          end

        with {:ok, handle} <- backend.open(line, direction, initial),
             :ok <- if(direction == :input, do: backend.watch(handle, line), else: :ok) do
          pin = %{line: line, direction: direction, handle: handle}

          {:cont,
           {:ok, %{s | pins: Map.put(s.pins, name, pin), lines: Map.put(s.lines, line, name)}}}
        else
          {:error, reason} -> {:halt, {:error, {:gpio_open_failed, name, line, reason}}}
        end
    end)
  end

  @impl true
  def describe(s) do
    sim? = function_exported?(s.backend, :stimulate, 2)

    %{
      kind: :gpio,
      pins: Map.new(s.pins, fn {name, p} -> {name, {p.line, p.direction}} end),
      reads: [:pin, :all],
      writes: if(sim?, do: [:pin, :stimulate], else: [:pin]),
      events: [:edge]
    }
  end

  @impl true
  def read({:pin, name}, s) do
    case Map.fetch(s.pins, name) do
      {:ok, pin} -> level(s.backend.read(pin.handle), s)
      :error -> {:error, {:no_such_pin, name}, s}
    end
  end

  def read(all, s) when all in [nil, :all] do
    Enum.reduce_while(s.pins, {:ok, %{}, s}, fn {name, pin}, {:ok, acc, s} ->
      case s.backend.read(pin.handle) do
        level when level in [0, 1] -> {:cont, {:ok, Map.put(acc, name, level), s}}
        {:error, reason} -> {:halt, {:error, {name, reason}, s}}
      end
    end)
  end

  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  defp level(level, s) when level in [0, 1], do: {:ok, level, s}
  defp level({:error, reason}, s), do: {:error, reason, s}

  @impl true
  def write({:pin, name, level} = arg, s) do
    case Map.fetch(s.pins, name) do
      {:ok, %{direction: :output} = pin} when level in [0, 1] ->
        case s.backend.write(pin.handle, level) do
          :ok -> {:ok, s}
          {:error, reason} -> {:error, reason, s}
        end

      {:ok, %{direction: :output}} ->
        {:error, {:bad_argument, arg}, s}

      {:ok, _input} ->
        {:error, {:not_an_output, name}, s}

      :error ->
        {:error, {:no_such_pin, name}, s}
    end
  end

  def write({:stimulate, name, level} = arg, s) do
    cond do
      not function_exported?(s.backend, :stimulate, 2) -> {:error, {:bad_argument, arg}, s}
      not Map.has_key?(s.pins, name) -> {:error, {:no_such_pin, name}, s}
      true -> stimulate(s.backend.stimulate(s.pins[name].handle, level), name, arg, s)
    end
  end

  def write(arg, s), do: {:error, {:bad_argument, arg}, s}

  defp stimulate(:ok, _name, _arg, s), do: {:ok, s}
  defp stimulate({:error, :not_an_input}, name, _arg, s), do: {:error, {:not_an_input, name}, s}
  defp stimulate({:error, _}, _name, arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  def handle_info(msg, s) do
    case s.backend.message(msg) do
      {:edge, line, level} when is_map_key(s.lines, line) ->
        {:events, [{:edge, Map.fetch!(s.lines, line), level}], s}

      _ ->
        {:events, [], s}
    end
  end
end
