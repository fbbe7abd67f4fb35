defmodule Tartarus.CodeCacheTest do
  # The code cache: manifests, binaries, checks against running agents, loading.
  use Tartarus.HostCase, async: false

  alias Tartarus.CodeCache

  # Compiles a small agent module from Erlang source to a binary, without loading it, so a
  # test can hold two versions of one module.
  defp agent_binary(module, version) do
    source = """
    -module('#{module}').
    -export(['__tartarus_agent__'/1, init/1, handle_arrival/2, handle_message/3,
             handle_move_failed/4, version/0]).
    '__tartarus_agent__'(ships) -> [].
    init(S) -> {stay, S}.
    handle_arrival(_, S) -> {stay, S}.
    handle_message(_, _, S) -> {stay, S}.
    handle_move_failed(_, _, _, S) -> {stay, S}.
    version() -> #{version}.
    """

    forms =
      source
      |> String.to_charlist()
      |> tokens([])
      |> Enum.map(fn toks ->
        {:ok, form} = :erl_parse.parse_form(toks)
        form
      end)

    {:ok, ^module, bin} = :compile.forms(forms, [:binary])
    {:ok, {^module, md5}} = :beam_lib.md5(bin)
    {md5, bin}
  end

  defp tokens(chars, acc) do
    case :erl_scan.tokens([], chars, 1) do
      {:done, {:ok, toks, _}, rest} -> tokens(rest, [toks | acc])
      {:more, _} -> Enum.reverse(acc)
      {:done, {:eof, _}, _} -> Enum.reverse(acc)
    end
  end

  defp fresh_module, do: :"Elixir.Tartarus.Test.Shipped#{System.unique_integer([:positive])}"

  describe "md5/1, manifest/1, fetch_binary/2" do
    test "for a module compiled by mix" do
      assert {:ok, md5} = CodeCache.md5(Probe)
      assert md5 == Probe.module_info(:md5)

      assert CodeCache.manifest([Probe, Tartarus.Examples.Echo]) ==
               {:ok,
                [{Probe, md5}, {Tartarus.Examples.Echo, Tartarus.Examples.Echo.module_info(:md5)}]}

      assert {:ok, bin} = CodeCache.fetch_binary(Probe, md5)
      assert {:ok, {Probe, ^md5}} = :beam_lib.md5(bin)
    end

    test "unknown modules and wrong md5s" do
      assert CodeCache.md5(NoSuchModule) == :error
      assert CodeCache.manifest([Probe, NoSuchModule]) == {:error, {:not_loaded, NoSuchModule}}
      assert CodeCache.manifest([]) == {:ok, []}
      assert CodeCache.fetch_binary(Probe, <<0::128>>) == {:error, {:no_object_code, Probe}}

      assert CodeCache.fetch_binary(NoSuchModule, <<0::128>>) ==
               {:error, {:no_object_code, NoSuchModule}}
    end

    test "remember/2 makes code without a file fetchable" do
      mod = fresh_module()
      {md5, bin} = agent_binary(mod, 1)
      assert CodeCache.fetch_binary(mod, md5) == {:error, {:no_object_code, mod}}
      assert CodeCache.remember(mod, bin) == :ok
      assert CodeCache.fetch_binary(mod, md5) == {:ok, bin}
    end
  end

  describe "check/1" do
    test "same version: :ok; missing or replaceable: {:need, mods}" do
      {:ok, manifest} = CodeCache.manifest([Probe])
      assert CodeCache.check(manifest) == :ok
      assert CodeCache.check([]) == :ok
      mod = fresh_module()
      assert CodeCache.check([{mod, <<1::128>>}]) == {:need, [mod]}
      # A loaded module that no agent runs may be replaced.
      {_, bin} = agent_binary(mod, 1)
      {:module, ^mod} = :code.load_binary(mod, ~c"test", bin)
      assert CodeCache.check(manifest ++ [{mod, <<1::128>>}]) == {:need, [mod]}
    end

    test "a different version of a module that live agents run is a conflict" do
      mod = fresh_module()
      {md5_1, bin_1} = agent_binary(mod, 1)
      {md5_2, bin_2} = agent_binary(mod, 2)
      assert md5_1 != md5_2
      assert CodeCache.load([{mod, md5_1, bin_1}]) == :ok
      assert mod.version() == 1

      h = host!()
      {:ok, id} = Tartarus.create_agent(h, mod, nil)
      assert CodeCache.check([{mod, md5_2}]) == {:error, {:code_conflict, mod}}
      assert CodeCache.load([{mod, md5_2, bin_2}]) == {:error, {:code_conflict, mod}}
      # The agent was not harmed.
      assert [%{id: ^id}] = Tartarus.agents(h)
      assert mod.version() == 1

      :ok = Tartarus.kill({id, h})
      assert eventually(fn -> CodeCache.load([{mod, md5_2, bin_2}]) == :ok end)
      assert mod.version() == 2
      assert CodeCache.md5(mod) == {:ok, md5_2}
    end
  end

  describe "load/1" do
    test "loads shipped code after checking its md5" do
      mod = fresh_module()
      {md5, bin} = agent_binary(mod, 7)
      assert CodeCache.load([{mod, md5, bin}]) == :ok
      assert mod.version() == 7
      assert CodeCache.fetch_binary(mod, md5) == {:ok, bin}
      # Loading the same version again is a no-op.
      assert CodeCache.load([{mod, md5, bin}]) == :ok
      assert CodeCache.load([]) == :ok
    end

    test "refuses bad md5s, bad binaries and junk" do
      mod = fresh_module()
      {_md5, bin} = agent_binary(mod, 1)
      assert CodeCache.load([{mod, <<0::128>>, bin}]) == {:error, {:bad_md5, mod}}
      assert {:error, {:bad_beam, _}} = CodeCache.load([{mod, <<0::128>>, "not a beam"}])
      assert CodeCache.load([:junk]) == {:error, {:bad_code, :junk}}
      assert CodeCache.md5(mod) == :error
    end

    test "an agent of shipped code runs and moves" do
      mod = fresh_module()
      {md5, bin} = agent_binary(mod, 1)
      :ok = CodeCache.load([{mod, md5, bin}])
      [a, b] = line!(2)
      {:ok, id} = Tartarus.create_mobile_agent(a, mod, :s)
      assert Tartarus.move({id, a}, b) == :ok
      assert {:ok, %{state: :s, host: {^b, _}}} = Tartarus.agent_info(id)
    end
  end
end
