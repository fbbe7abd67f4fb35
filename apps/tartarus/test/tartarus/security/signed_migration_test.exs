defmodule Tartarus.Security.SignedMigrationTest do
  # Signed agents between hosts with trust lists: good agents move; unknown issuers,
  # unsigned agents, tampered state and tampered code are refused and stay at the source.
  use ExUnit.Case, async: false

  alias Tartarus.Migration.{Messages, Protocol}

  alias Tartarus.{CodeCache, Envelope}
  alias Tartarus.Security.{Keys, TrustList}
  alias Tartarus.Examples.Echo

  setup do
    issuer = Keys.generate()
    host_keys = Keys.generate()
    trust = TrustList.new([issuer.public, host_keys.public])
    tag = System.unique_integer([:positive])
    sec = [security: [keys: host_keys, trust: trust]]
    {:ok, a} = Tartarus.start_host(:"sa_#{tag}", sec)
    {:ok, b} = Tartarus.start_host(:"sb_#{tag}", sec)
    on_exit(fn -> Enum.each([a, b], &Tartarus.stop_host/1) end)
    %{a: a, b: b, issuer: issuer, host_keys: host_keys}
  end

  test "an agent signed by a trusted issuer moves between trusting hosts", %{
    a: a,
    b: b,
    issuer: issuer
  } do
    {:ok, id} = Tartarus.create_mobile_agent(a, Echo, :ok, issuer: issuer)
    assert :ok = Tartarus.move({id, a}, b)
    assert :ok = Tartarus.move({id, b}, a)
    assert {:ok, ^a} = Tartarus.request({id, a}, :where)
  end

  test "unknown issuers and unsigned agents are refused and stay home", %{a: a, b: b} do
    {:ok, stranger} = Tartarus.create_mobile_agent(a, Echo, :s, issuer: Keys.generate())
    assert {:error, {:untrusted, {:unknown_issuer, _}}} = Tartarus.move({stranger, a}, b)
    assert {:ok, ^a} = Tartarus.request({stranger, a}, :where)

    {:ok, unsigned} = Tartarus.create_mobile_agent(a, Echo, :u)
    assert {:error, {:untrusted, {:missing_field, :issuer}}} = Tartarus.move({unsigned, a}, b)
    assert Tartarus.status(b).counts.refused == 2
  end

  test "a bad issuer option is refused with a clear error", %{a: a} do
    assert {:error, "invalid options given to Tartarus.create_agent/4 for key :issuer" <> _} =
             Tartarus.create_mobile_agent(a, Echo, nil, issuer: :me)
  end

  # Forged hand-offs, sent straight to the destination host as another node would.
  defp forged_prepare(b, env, manifest, mig) do
    {:ok, pid} = Tartarus.Host.whereis(b)

    send(
      pid,
      Messages.prepare(self(), mig, {:elsewhere, node()}, self(), :move, env, manifest, [])
    )

    receive do
      {:"$tartarus_refused", ^mig, reason} -> {:refused, reason}
      {:"$tartarus_prepared", ^mig, _copy, pid} -> {:prepared, pid}
    after
      2_000 -> :timeout
    end
  end

  defp signed_env(issuer, host_keys, state, mig) do
    env = %Envelope{
      id: Envelope.new_id(),
      module: Echo,
      name: "forged",
      state: state,
      rng: Envelope.seed_rng(1)
    }

    {:ok, manifest} = CodeCache.manifest([Echo])
    env = Tartarus.Security.issue(env, manifest, issuer)

    prepare =
      Messages.prepare(self(), mig, {:elsewhere, node()}, self(), :move, env, manifest, [])

    {elem(Tartarus.Security.seal_prepare(prepare, host_keys), 6), manifest}
  end

  test "tampered state is refused", %{b: b, issuer: issuer, host_keys: host_keys} do
    mig = {"incarnat", make_ref()}
    {env, manifest} = signed_env(issuer, host_keys, %{balance: 1}, mig)

    assert {:refused, {:untrusted, :bad_signature}} =
             forged_prepare(b, %{env | state: %{balance: 1_000_000}}, manifest, mig)

    # The untouched envelope is admitted (then left to time out unpaused).
    assert {:prepared, _} = forged_prepare(b, env, manifest, mig)
  end

  test "tampered code is refused", %{b: b, issuer: issuer, host_keys: host_keys} do
    mig = {"incarnat", make_ref()}
    {env, [{Echo, _md5}]} = signed_env(issuer, host_keys, :s, mig)
    forged_manifest = [{Echo, :crypto.strong_rand_bytes(16)}]
    assert {:refused, {:untrusted, :bad_signature}} = forged_prepare(b, env, forged_manifest, mig)
  end

  test "a replayed seal (another migration id) is refused", %{
    b: b,
    issuer: issuer,
    host_keys: host_keys
  } do
    {env, manifest} = signed_env(issuer, host_keys, :s, {"incarnat", make_ref()})

    assert {:refused, {:untrusted, :bad_signature}} =
             forged_prepare(b, env, manifest, {"incarnat", make_ref()})
  end
end
