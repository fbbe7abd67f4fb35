defmodule Tartarus.Security.Admission do
  @limit {:or, [:pos_integer, {:in, [:infinity]}]}
  @limit_words "a positive integer or :infinity"

  @schema [
    max_resident_agents: [
      type: @limit,
      expected: @limit_words,
      default: 2_000,
      doc:
        "agents a host may hold at once, paused (arriving) copies included; an arrival is " <>
          "refused when `resident` (the agents the host already holds, as the host counts " <>
          "them) has reached it. This is what stops a clone storm. The default leaves room " <>
          "for `mix tartarus.bench migration --agents 1000` (an agent briefly counts at both " <>
          "ends of a hand-off)"
    ],
    max_message_bytes: [
      type: @limit,
      expected: @limit_words,
      default: 8 * 1024 * 1024,
      doc:
        "size of the whole hand-off message (envelope and shipped code), checked before " <>
          "anything in it is looked at"
    ],
    max_envelope_bytes: [
      type: @limit,
      expected: @limit_words,
      default: 2 * 1024 * 1024,
      doc: "size of the agent's envelope alone (state, payload and metadata, without code)"
    ],
    max_payload_bytes: [
      type: @limit,
      expected: @limit_words,
      default: 1024 * 1024,
      doc: "size of the agent's state and data payload"
    ],
    max_hops: [
      type: @limit,
      expected: @limit_words,
      default: :infinity,
      doc:
        "migrations an agent may make in its life; `hops` counts them including the " <>
          "current one, so an arrival with `hops > max_hops` is refused"
    ],
    rate: [
      type: {:or, [{:tuple, [:pos_integer, :pos_integer]}, {:in, [:infinity]}]},
      expected: "{count, interval_ms} with positive integers, or :infinity",
      default: {100_000, 1_000},
      doc:
        "admissions per source host: `{count, interval_ms}` allows bursts of `count` and " <>
          "refills `count` tokens every `interval_ms` (a token bucket per source); " <>
          "`:infinity` turns it off. The default is well above the hops per second one " <>
          "source host can send (the BEAM floor between two nodes here is about 25,000/s)"
    ]
  ]

  @moduledoc """
  A host's admission policy for arriving agents, as pure data and one pure decision function.

  The host keeps an `Admission` state, asks `admit/3` about every arriving agent *after* its
  signature was checked (see `Tartarus.Security.Signer`), and keeps the new state only when the
  agent is admitted. Nothing here runs a process or reads a clock: the caller passes `now_ms`
  (any monotonic millisecond clock, e.g. `Tartarus.Clock.monotonic_time(:millisecond)`).

      {:ok, admission} = Tartarus.Security.Admission.new(max_resident_agents: 100, rate: {10, 1_000})

      request = %{source: :"host_a@lab", envelope_bytes: 2_048, payload_bytes: 512, hops: 3, resident: 12}

      case Tartarus.Security.Admission.admit(admission, request, Tartarus.Clock.monotonic_time(:millisecond)) do
        {:ok, admission} -> admission
        {:error, reason} -> # refuse: send reason back to the sender, emit an event
      end

  ## Options

  The admission policy owns every limit a host applies to one arrival; each option has one
  meaning, and a host started with no options gets the defaults below, all finite except
  `:max_hops` (an agent's own `ttl:` bounds its hops). They are chosen so that a clone storm
  (an agent that clones itself on every arrival) stops at the resident limit within about a
  second, and the workloads in the repository (tests, `mix tartarus.bench`, the emulator's
  100,000 agents on 10,000 hosts) never meet them.

  #{Tartarus.Options.docs(@schema)}

  Bad options are refused with a message naming the option, what was expected and what
  arrived:

      iex> Tartarus.Security.Admission.new(max_hops: -1)
      {:error, "invalid options given to Tartarus.Security.Admission.new/1 for key :max_hops: expected a positive integer or :infinity, got: -1"}

  ## Decisions

  `admit/3` checks, in this order, and answers the first failure:

    1. `{:envelope_too_large, bytes, max}`, then `{:payload_too_large, bytes, max}`;
    2. `{:ttl_expired, hops}`;
    3. `{:too_many_agents, max}` - `max` is the host's limit;
    4. `{:rate_limited, source}`.

  A refused arrival consumes no token: only admissions count against a source's rate.
  `:max_message_bytes` is not checked by `admit/3`: the host checks it on the raw hand-off
  message (`Tartarus.Wire.check_prepare/2`) before it looks inside; read it with
  `max_message_bytes/1`.

  A request that is not a map with the five fields gets
  `{:error, {:invalid_request, message}}`; it never raises.

  ## Token buckets

  Buckets are kept per source in the state. A bucket that has refilled is the same as no bucket,
  so `prune/2` drops those; `admit/3` does so itself once it tracks more than 1,024 sources,
  so memory stays bounded by the sources active within one refill. Token arithmetic is in
  integers (scaled by `interval_ms`), so refills are exact.
  """

  defmodule Policy do
    @moduledoc """
    The validated limits of a `Tartarus.Security.Admission` policy; see that module for each
    field.
    """
    @enforce_keys [
      :max_resident_agents,
      :max_message_bytes,
      :max_envelope_bytes,
      :max_payload_bytes,
      :max_hops,
      :rate
    ]
    defstruct @enforce_keys

    @typedoc "A limit: a positive integer or `:infinity`."
    @type limit :: pos_integer() | :infinity

    @typedoc "Validated admission limits."
    @type t :: %__MODULE__{
            max_resident_agents: limit(),
            max_message_bytes: limit(),
            max_envelope_bytes: limit(),
            max_payload_bytes: limit(),
            max_hops: limit(),
            rate: {pos_integer(), pos_integer()} | :infinity
          }
  end

  defstruct [:policy, buckets: %{}]

  @typedoc "A policy with the token buckets of the sources seen so far."
  @type t :: %__MODULE__{
          policy: Policy.t(),
          buckets: %{term() => {scaled_tokens :: non_neg_integer(), at_ms :: integer()}}
        }

  @typedoc "What `admit/3` needs to know about one arrival."
  @type request :: %{
          required(:source) => term(),
          required(:envelope_bytes) => non_neg_integer(),
          required(:payload_bytes) => non_neg_integer(),
          required(:hops) => non_neg_integer(),
          required(:resident) => non_neg_integer(),
          optional(atom()) => term()
        }

  @typedoc "Why an arrival was refused."
  @type refusal ::
          {:too_many_agents, pos_integer()}
          | {:envelope_too_large, non_neg_integer(), pos_integer()}
          | {:payload_too_large, non_neg_integer(), pos_integer()}
          | {:ttl_expired, non_neg_integer()}
          | {:rate_limited, term()}
          | {:invalid_request, String.t()}

  @doc "The schema of the options (see `Tartarus.Options`), with their defaults."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Validates `opts` (see "Options") and builds an admission state with no buckets.

  ## Examples

      iex> {:ok, adm} = Tartarus.Security.Admission.new(max_hops: 3)
      iex> {adm.policy.max_hops, adm.policy.max_resident_agents}
      {3, 2000}
      iex> Tartarus.Security.Admission.new(rate: {0, 10})
      {:error, "invalid options given to Tartarus.Security.Admission.new/1 for key :rate: expected {count, interval_ms} with positive integers, or :infinity, got: {0, 10}"}
      iex> Tartarus.Security.Admission.new(max_agents: 3)
      {:error, "invalid options given to Tartarus.Security.Admission.new/1: unknown key :max_agents, known keys: [:max_resident_agents, :max_message_bytes, :max_envelope_bytes, :max_payload_bytes, :max_hops, :rate]"}

  `where` names the caller in error messages (a host passes `"Tartarus.start_host/2"`
  with the key path `[:admission]`, see `Tartarus.Options`).
  """
  @spec new(keyword(), String.t()) :: {:ok, t()} | {:error, String.t()}
  def new(opts \\ [], where \\ "Tartarus.Security.Admission.new/1") do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, where) do
      {:ok, %__MODULE__{policy: struct!(Policy, opts)}}
    end
  end

  @doc """
  The largest hand-off message (envelope and code, in bytes) the policy lets a host read.

      iex> Tartarus.Security.Admission.max_message_bytes(Tartarus.Security.Admission.new!())
      8_388_608
  """
  @spec max_message_bytes(t()) :: Policy.limit()
  def max_message_bytes(%__MODULE__{policy: policy}), do: policy.max_message_bytes

  @doc "Like `new/1` but raises `ArgumentError` on a bad option."
  @spec new!(keyword()) :: t()
  def new!(opts \\ []) do
    case new(opts) do
      {:ok, state} -> state
      {:error, message} -> raise ArgumentError, message
    end
  end

  @doc """
  Decides whether one arriving agent is admitted at `now_ms`.

  On `{:ok, state}` the source's bucket lost one token; on an error the state is unchanged,
  so the caller keeps its old state.

  ## Examples

      iex> adm = Tartarus.Security.Admission.new!(max_hops: 2, rate: {1, 1_000})
      iex> req = %{source: :a, envelope_bytes: 10, payload_bytes: 5, hops: 1, resident: 0}
      iex> {:ok, adm} = Tartarus.Security.Admission.admit(adm, req, 0)
      iex> Tartarus.Security.Admission.admit(adm, req, 10)
      {:error, {:rate_limited, :a}}
      iex> Tartarus.Security.Admission.admit(adm, %{req | hops: 3}, 2_000)
      {:error, {:ttl_expired, 3}}
  """
  @spec admit(t(), request(), integer()) :: {:ok, t()} | {:error, refusal()}
  def admit(%__MODULE__{policy: policy} = state, request, now_ms) when is_integer(now_ms) do
    with :ok <- check_request(request),
         :ok <- within(request.envelope_bytes, policy.max_envelope_bytes, :envelope_too_large),
         :ok <- within(request.payload_bytes, policy.max_payload_bytes, :payload_too_large),
         :ok <- check_hops(request.hops, policy.max_hops),
         :ok <- check_resident(request.resident, policy.max_resident_agents) do
      take_token(state, request.source, now_ms)
    end
  end

  @doc """
  The whole tokens left to `source` at `now_ms` (`:infinity` when there is no rate limit).

  ## Examples

      iex> adm = Tartarus.Security.Admission.new!(rate: {4, 1_000})
      iex> Tartarus.Security.Admission.tokens(adm, :a, 0)
      4
  """
  @spec tokens(t(), term(), integer()) :: non_neg_integer() | :infinity
  def tokens(%__MODULE__{policy: %Policy{rate: :infinity}}, _source, _now_ms), do: :infinity

  def tokens(%__MODULE__{policy: %Policy{rate: {_count, interval}}} = state, source, now_ms) do
    div(current(state, source, now_ms), interval)
  end

  @doc """
  Drops the buckets that are full again at `now_ms`; they mean the same as no bucket.
  """
  @spec prune(t(), integer()) :: t()
  def prune(%__MODULE__{policy: %Policy{rate: :infinity}} = state, _now_ms),
    do: %{state | buckets: %{}}

  def prune(%__MODULE__{policy: %Policy{rate: rate}, buckets: buckets} = state, now_ms),
    do: %{state | buckets: prune_buckets(buckets, rate, now_ms)}

  defp prune_buckets(buckets, {count, interval}, now_ms) do
    full = count * interval

    for {_source, {scaled, at}} = entry <- buckets,
        min(full, scaled + count * max(now_ms - at, 0)) < full,
        into: %{},
        do: entry
  end

  @doc "Turns a refusal into a sentence, for logs and the sender."
  @spec format_refusal(refusal()) :: String.t()
  def format_refusal({:too_many_agents, max}), do: "host is full: at most #{max} resident agents"

  def format_refusal({:envelope_too_large, bytes, max}),
    do: "envelope too large: #{bytes} bytes, at most #{max}"

  def format_refusal({:payload_too_large, bytes, max}),
    do: "payload too large: #{bytes} bytes, at most #{max}"

  def format_refusal({:ttl_expired, hops}), do: "agent made too many hops: #{hops}"
  def format_refusal({:rate_limited, source}), do: "too many arrivals from #{inspect(source)}"
  def format_refusal({:invalid_request, message}), do: message

  ## Token bucket (tokens scaled by interval_ms: +count per ms, -interval per admission)

  defp take_token(%__MODULE__{policy: %Policy{rate: :infinity}} = state, _source, _now),
    do: {:ok, state}

  defp take_token(%__MODULE__{policy: %Policy{rate: {_, interval}}} = state, source, now_ms) do
    available = current(state, source, now_ms)

    if available >= interval do
      buckets = Map.put(state.buckets, source, {available - interval, now_ms})
      {:ok, %{state | buckets: bound(buckets, state.policy.rate, now_ms)}}
    else
      {:error, {:rate_limited, source}}
    end
  end

  # Every host has a rate limit by default, and nothing else prunes its buckets: past
  # @prune_above sources, full buckets are dropped (every @prune_every admissions of a new
  # source, so the cost stays amortized).
  @prune_above 1_024
  @prune_every 256

  defp bound(buckets, rate, now_ms) do
    size = map_size(buckets)

    if size > @prune_above and rem(size, @prune_every) == 0,
      do: prune_buckets(buckets, rate, now_ms),
      else: buckets
  end

  defp current(
         %__MODULE__{policy: %Policy{rate: {count, interval}}, buckets: buckets},
         source,
         now
       ) do
    full = count * interval

    case buckets do
      %{^source => {scaled, at}} -> min(full, scaled + count * max(now - at, 0))
      %{} -> full
    end
  end

  ## Request checks

  @request_fields [:source, :envelope_bytes, :payload_bytes, :hops, :resident]

  # The well-formed request (every arrival's) in one match; the others get a message.
  defp check_request(%{source: _, envelope_bytes: e, payload_bytes: p, hops: h, resident: r})
       when is_integer(e) and e >= 0 and is_integer(p) and p >= 0 and is_integer(h) and h >= 0 and
              is_integer(r) and r >= 0,
       do: :ok

  defp check_request(%{} = request) do
    case Enum.reject(@request_fields, &Map.has_key?(request, &1)) do
      [] ->
        Enum.find_value([:envelope_bytes, :payload_bytes, :hops, :resident], :ok, fn key ->
          value = Map.fetch!(request, key)

          unless is_integer(value) and value >= 0 do
            {:error,
             {:invalid_request,
              "invalid admission request field #{inspect(key)}: " <>
                "expected a non-negative integer, got: #{inspect(value)}"}}
          end
        end)

      missing ->
        {:error,
         {:invalid_request,
          "invalid admission request: missing #{Enum.map_join(missing, ", ", &inspect/1)}"}}
    end
  end

  defp check_request(other) do
    {:error,
     {:invalid_request,
      "invalid admission request: expected a map with #{Enum.map_join(@request_fields, ", ", &inspect/1)}, got: #{inspect(other)}"}}
  end

  defp within(_value, :infinity, _tag), do: :ok
  defp within(value, max, _tag) when value <= max, do: :ok
  defp within(value, max, tag), do: {:error, {tag, value, max}}

  defp check_hops(_hops, :infinity), do: :ok
  defp check_hops(hops, max) when hops <= max, do: :ok
  defp check_hops(hops, _max), do: {:error, {:ttl_expired, hops}}

  defp check_resident(_resident, :infinity), do: :ok
  defp check_resident(resident, max) when resident < max, do: :ok
  defp check_resident(_resident, max), do: {:error, {:too_many_agents, max}}
end
