defmodule Tartarus.Security.AdmissionTest do
  use ExUnit.Case, async: true

  alias Tartarus.Security.Admission

  doctest Admission

  @ok %{source: :a, envelope_bytes: 100, payload_bytes: 50, hops: 1, resident: 0}

  describe "options" do
    test "defaults" do
      assert {:ok, %Admission{policy: policy, buckets: %{}}} = Admission.new()
      # Safe defaults: every per-arrival limit is finite except hops (see the moduledoc).
      assert policy.max_resident_agents == 1_000
      assert policy.max_message_bytes == 8 * 1024 * 1024
      assert policy.max_envelope_bytes == 2 * 1024 * 1024
      assert policy.max_payload_bytes == 1024 * 1024
      assert policy.max_hops == :infinity
      assert policy.rate == {20_000, 1_000}
    end

    test "every limit accepts a positive integer or :infinity" do
      for key <- [
            :max_resident_agents,
            :max_message_bytes,
            :max_envelope_bytes,
            :max_payload_bytes,
            :max_hops
          ] do
        assert {:ok, _} = Admission.new([{key, 1}])
        assert {:ok, _} = Admission.new([{key, :infinity}])

        for bad <- [0, -1, 1.5, "3", nil] do
          assert Admission.new([{key, bad}]) ==
                   {:error,
                    "invalid options given to Tartarus.Security.Admission.new/1 for key #{inspect(key)}: expected a positive integer or :infinity, got: #{inspect(bad)}"}
        end
      end
    end

    test "the message names the option, the expectation and the value" do
      assert Admission.new(max_hops: -1) ==
               {:error,
                "invalid options given to Tartarus.Security.Admission.new/1 for key :max_hops: expected a positive integer or :infinity, got: -1"}

      assert_raise ArgumentError,
                   "invalid options given to Tartarus.Security.Admission.new/1 for key :rate: expected {count, interval_ms} with positive integers, or :infinity, got: 5",
                   fn -> Admission.new!(rate: 5) end
    end

    test "non-keyword options are refused" do
      assert Admission.new(%{max_hops: 1}) ==
               {:error,
                "invalid options given to Tartarus.Security.Admission.new/1: expected a keyword list, got: %{max_hops: 1}"}
    end
  end

  describe "admit/3" do
    test "admits within limits and leaves the state unchanged without a rate" do
      adm = Admission.new!(rate: :infinity)
      assert {:ok, ^adm} = Admission.admit(adm, @ok, 0)
    end

    test "refuses oversized envelopes and payloads" do
      adm = Admission.new!(max_envelope_bytes: 100, max_payload_bytes: 10)

      assert {:error, {:envelope_too_large, 101, 100}} =
               Admission.admit(adm, %{@ok | envelope_bytes: 101}, 0)

      assert {:error, {:payload_too_large, 50, 10}} = Admission.admit(adm, @ok, 0)
    end

    test "refuses agents past their hop limit" do
      adm = Admission.new!(max_hops: 3)
      assert {:ok, _} = Admission.admit(adm, %{@ok | hops: 3}, 0)
      assert {:error, {:ttl_expired, 4}} = Admission.admit(adm, %{@ok | hops: 4}, 0)
    end

    test "refuses arrivals on a full host" do
      adm = Admission.new!(max_resident_agents: 2)
      assert {:ok, _} = Admission.admit(adm, %{@ok | resident: 1}, 0)
      assert {:error, {:too_many_agents, 2}} = Admission.admit(adm, %{@ok | resident: 2}, 0)
    end

    test "bad requests get a clear error, never a crash" do
      adm = Admission.new!()

      assert {:error, {:invalid_request, "invalid admission request: missing :hops, :resident"}} =
               Admission.admit(adm, Map.drop(@ok, [:hops, :resident]), 0)

      assert {:error,
              {:invalid_request,
               "invalid admission request field :payload_bytes: expected a non-negative integer, got: -5"}} =
               Admission.admit(adm, %{@ok | payload_bytes: -5}, 0)

      assert {:error, {:invalid_request, "invalid admission request: expected a map" <> _}} =
               Admission.admit(adm, :garbage, 0)
    end

    test "refusals read as sentences" do
      assert Admission.format_refusal({:envelope_too_large, 10, 5}) ==
               "envelope too large: 10 bytes, at most 5"

      assert Admission.format_refusal({:rate_limited, :a}) == "too many arrivals from :a"
    end
  end

  describe "token bucket" do
    test "allows a burst, then refills over time" do
      adm = Admission.new!(rate: {3, 1_000})

      {adm, results} =
        Enum.reduce(1..4, {adm, []}, fn _, {adm, acc} ->
          case Admission.admit(adm, @ok, 0) do
            {:ok, adm} -> {adm, [:ok | acc]}
            {:error, reason} -> {adm, [reason | acc]}
          end
        end)

      assert Enum.reverse(results) == [:ok, :ok, :ok, {:rate_limited, :a}]
      assert Admission.tokens(adm, :a, 0) == 0

      # 3 tokens per 1000 ms: one token every 333.3 ms, exactly.
      assert {:error, {:rate_limited, :a}} = Admission.admit(adm, @ok, 333)
      assert {:ok, adm} = Admission.admit(adm, @ok, 334)
      assert Admission.tokens(adm, :a, 334) == 0
      assert Admission.tokens(adm, :a, 334 + 667) == 2
    end

    test "a bucket never holds more than its capacity" do
      adm = Admission.new!(rate: {2, 100})
      {:ok, adm} = Admission.admit(adm, @ok, 0)
      assert Admission.tokens(adm, :a, 1_000_000) == 2
    end

    test "sources have their own buckets" do
      adm = Admission.new!(rate: {1, 1_000})
      {:ok, adm} = Admission.admit(adm, @ok, 0)
      assert {:error, {:rate_limited, :a}} = Admission.admit(adm, @ok, 1)
      assert {:ok, _} = Admission.admit(adm, %{@ok | source: :b}, 1)
    end

    test "refused arrivals consume no token" do
      adm = Admission.new!(rate: {1, 1_000}, max_hops: 1)
      assert {:error, {:ttl_expired, 2}} = Admission.admit(adm, %{@ok | hops: 2}, 0)
      assert {:ok, _} = Admission.admit(adm, @ok, 0)
    end

    test "a clock going backwards refills nothing" do
      adm = Admission.new!(rate: {1, 1_000})
      {:ok, adm} = Admission.admit(adm, @ok, 5_000)
      assert {:error, {:rate_limited, :a}} = Admission.admit(adm, @ok, 0)
    end

    test "admit/3 keeps the buckets bounded by the sources active within one refill" do
      # One token per 10 ms: a bucket is full again 10 ms after its admission.
      adm = Admission.new!(rate: {1, 10})

      adm =
        Enum.reduce(1..5_000, adm, fn i, adm ->
          {:ok, adm} = Admission.admit(adm, %{@ok | source: {:h, i}}, i * 20)
          adm
        end)

      assert map_size(adm.buckets) <= 1_024 + 256
      # The latest source still has its (empty) bucket.
      assert {:error, {:rate_limited, {:h, 5_000}}} =
               Admission.admit(adm, %{@ok | source: {:h, 5_000}}, 5_000 * 20)
    end

    test "prune drops the buckets that are full again" do
      # 2 tokens per 1000 ms: a bucket one token short is full again 500 ms later.
      adm = Admission.new!(rate: {2, 1_000})
      {:ok, adm} = Admission.admit(adm, @ok, 0)
      {:ok, adm} = Admission.admit(adm, %{@ok | source: :b}, 900)

      assert adm |> Admission.prune(499) |> Map.fetch!(:buckets) |> Map.keys() |> Enum.sort() == [
               :a,
               :b
             ]

      assert adm |> Admission.prune(500) |> Map.fetch!(:buckets) |> Map.keys() == [:b]
      assert adm |> Admission.prune(1_400) |> Map.fetch!(:buckets) == %{}
    end
  end
end
