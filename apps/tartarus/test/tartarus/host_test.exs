defmodule Tartarus.HostTest do
  use Tartarus.HostCase, async: false

  alias Tartarus.Host

  doctest Host

  test "address?/1" do
    for ok <- [:a, "a", {:a, :n@h}, {"a", :n@h}, String.duplicate("x", 255)],
        do: assert(Host.address?(ok))

    for bad <- [
          nil,
          true,
          false,
          3,
          "",
          String.duplicate("x", 256),
          {:a, nil},
          {:a, "n"},
          {3, :n},
          [:a]
        ] do
      refute Host.address?(bad)
    end
  end

  test "address/1" do
    assert Host.address(:a) == {:a, node()}
    assert Host.address({:a, :n@h}) == {:a, :n@h}
  end

  test "whereis/1 and local/1" do
    h = host!()
    assert {:ok, pid} = Host.whereis(h)
    assert is_pid(pid)
    assert {:ok, %{ref: ref}} = Host.local(h)
    assert ref == addr(h)
    x = unique_name()
    assert Host.whereis(x) == {:error, {:unknown_host, addr(x)}}
    assert Host.whereis(3) == {:error, {:unknown_host, 3}}
    assert Host.local(x) == {:error, {:unknown_host, x}}
    assert Host.local({h, :other@node}) == {:error, {:unknown_host, {h, :other@node}}}
  end

  test "the schema documents every option in start_host/2's docs" do
    {:docs_v1, _, _, _, _, _, docs} = Code.fetch_docs(Tartarus)

    doc =
      Enum.find_value(docs, fn
        {{:function, :start_host, 2}, _, _, %{"en" => doc}, _} -> doc
        _ -> nil
      end)

    for {key, _} <- Tartarus.Options.Platform.host_schema(),
        do: assert(doc =~ "`#{inspect(key)}`")
  end

  test "an agent arriving while its destination stops is refused and stays where it was; the destination's server does not crash" do
    [a, b] = line!(2)
    {:ok, server} = Host.whereis(b)
    # A stopping host: its supervisor stops the keeper (which marks the host stopping) before
    # the server.
    :ok = Supervisor.terminate_child(Host.via(:host_sup, b), :keeper)
    id = agent!(a)
    assert {:error, _} = Tartarus.move({id, a}, b)
    assert_receive {:probe_move_failed, ^id, _, _, ctx}
    assert ctx.host == addr(a)
    assert {:ok, ^server} = Host.whereis(b)
    assert Process.alive?(server)
    assert %{} = probe_state({id, a})
  end
end
