defmodule Tartarus.ReviewRegressionsTest do
  # Regressions for faults found by reviewing the migration core.
  use Tartarus.HostCase, async: false

  alias Tartarus.{Envelope, Fault}
  alias Tartarus.Security.{Keys, TrustList}

  test "a seal of the wrong shape is refused by a trusting host, which stays up" do
    keys = Keys.generate()
    b = host!(security: [trust: TrustList.new([keys.public])])
    {:ok, pid} = Tartarus.Host.whereis(b)
    {:ok, manifest} = Tartarus.CodeCache.manifest([Tartarus.Examples.Echo])

    env = %Envelope{
      id: Envelope.new_id(),
      module: Tartarus.Examples.Echo,
      rng: Envelope.seed_rng(1),
      issuer: <<0::256>>,
      signature: %{issuer: <<0::512>>, hop: :x}
    }

    mig = {"incarnat", make_ref()}

    send(
      pid,
      Tartarus.Migration.Messages.prepare(
        self(),
        mig,
        {:x, node()},
        self(),
        :move,
        env,
        manifest,
        []
      )
    )

    assert_receive {:"$tartarus_refused", ^mig, {:untrusted, :bad_signature}}, 2_000
    assert Process.alive?(pid)
  end

  test "names are compared, not matched: :_ is nobody's name" do
    a = host!()
    _id = agent!(a, %{}, name: "alice")
    assert {:error, :not_found} = Tartarus.request({:_, a}, :state)
    assert {:error, :not_found} = Tartarus.kill({:"$1", a})
    assert [_] = Tartarus.agents(a)
  end

  test "a kill during a hand-off aborts it: the paused copy goes away, nothing is left" do
    [a, b] = [host!(), host!()]
    id = agent!(a)
    Fault.install(:prepared, {:once, {:pause, self()}})
    on_exit(fn -> Fault.clear(:prepared) end)
    :ok = Tartarus.post({id, a}, {:do, {:move, b}})
    assert_receive {:fault_paused, :prepared, s_pid, _new}, 2_000
    assert :ok = Tartarus.kill({id, a})
    refute Process.alive?(s_pid)
    # The destination's copy asks the source, learns of the abort and stops.
    assert eventually(fn -> Tartarus.Host.call(b, :paused) == 0 end, 8_000)
    assert Tartarus.agents(a) == [] and Tartarus.agents(b) == []
  end

  test "a move to the same host survives the host dying between decision and commit" do
    dir = Path.join(System.tmp_dir!(), "same_host_#{System.unique_integer([:positive])}")
    name = unique_name()
    {:ok, h} = Tartarus.start_host(name, data_dir: dir, migration_timeout: 300)
    {:ok, id} = Tartarus.create_mobile_agent(h, Tartarus.Examples.Echo, :kept)
    Fault.install(:committing, {:once, {:pause, self()}})
    on_exit(fn -> Fault.clear(:committing) end)
    :ok = Tartarus.post({id, h}, {:go, h})
    assert_receive {:fault_paused, :committing, _s_pid, _new}, 2_000

    # The host dies (not a clean stop): its supervisor is killed outright.
    [{sup, _}] = Registry.lookup(Tartarus.HostRegistry, {:host_sup, name})
    Process.flag(:trap_exit, true)
    Process.exit(sup, :kill)
    assert eventually(fn -> Tartarus.hosts() |> Enum.all?(&(&1 != h)) end, 2_000)

    {:ok, ^h} = Tartarus.start_host(name, data_dir: dir, migration_timeout: 300)
    assert eventually(fn -> length(Tartarus.agents(h)) == 1 end, 5_000)
    assert {:ok, :kept} = Tartarus.request({id, h}, :state)
    :ok = Tartarus.stop_host(h)
    File.rm_rf!(dir)
  end
end
