defmodule Tartarus.Security.SignerTest do
  use ExUnit.Case, async: true

  alias Tartarus.Security.{Keys, Signer, TrustList}

  doctest Signer
  doctest TrustList

  setup do
    issuer = Keys.generate()
    %{issuer: issuer, trust: TrustList.new([issuer.public])}
  end

  describe "envelopes" do
    test "good path: a signed envelope from a trusted issuer verifies", %{
      issuer: issuer,
      trust: trust
    } do
      envelope =
        Signer.sign_envelope(
          %{id: "a1", module: Foo, state: %{n: 1, items: [1, 2.5]}, hops: 2},
          issuer
        )

      assert envelope.issuer == issuer.public
      assert :ok = Signer.verify_envelope(envelope, trust)
    end

    test "the signature does not depend on how the map was built", %{issuer: issuer, trust: trust} do
      envelope = Signer.sign_envelope(%{a: 1, b: %{c: 2, d: 3}}, issuer)
      rebuilt = Map.new(Enum.reverse(Map.to_list(%{envelope | b: Map.new(d: 3, c: 2)})))

      assert :ok = Signer.verify_envelope(rebuilt, trust)
    end

    test "tampered state is refused", %{issuer: issuer, trust: trust} do
      envelope = Signer.sign_envelope(%{id: "a1", state: %{balance: 10}}, issuer)

      assert {:error, :bad_signature} =
               Signer.verify_envelope(put_in(envelope.state.balance, 1_000_000), trust)

      assert {:error, :bad_signature} =
               Signer.verify_envelope(Map.put(envelope, :extra, true), trust)

      assert {:error, :bad_signature} =
               Signer.verify_envelope(%{envelope | signature: :binary.copy(<<0>>, 64)}, trust)

      assert {:error, :bad_signature} =
               Signer.verify_envelope(%{envelope | signature: "x"}, trust)
    end

    test "an envelope re-signed by an unknown issuer is refused, naming its fingerprint",
         %{issuer: issuer, trust: trust} do
      envelope = Signer.sign_envelope(%{state: 1}, issuer)
      mallory = Keys.generate()
      forged = Signer.sign_envelope(%{envelope | state: 2}, mallory)

      assert {:error, {:unknown_issuer, fingerprint}} = Signer.verify_envelope(forged, trust)
      assert fingerprint == Keys.fingerprint(mallory.public)
    end

    test "swapping in a trusted issuer's key does not help a forger", %{
      issuer: issuer,
      trust: trust
    } do
      forged = Signer.sign_envelope(%{state: 2}, Keys.generate())

      assert {:error, :bad_signature} =
               Signer.verify_envelope(%{forged | issuer: issuer.public}, trust)
    end

    test "an unsigned envelope is refused, naming the missing field", %{trust: trust} do
      assert {:error, {:missing_field, :issuer}} = Signer.verify_envelope(%{state: 1}, trust)

      assert {:error, {:missing_field, :signature}} =
               Signer.verify_envelope(%{state: 1, issuer: <<0::256>>}, trust)
    end

    test "input of the wrong shape gets an error, not a crash", %{trust: trust} do
      assert {:error, {:invalid_envelope, "expected a map with :issuer and :signature, got: [1]"}} =
               Signer.verify_envelope([1], trust)
    end

    test "signing twice replaces the old signature", %{issuer: issuer, trust: trust} do
      once = Signer.sign_envelope(%{state: 1}, issuer)
      twice = Signer.sign_envelope(%{once | state: 2}, issuer)
      assert :ok = Signer.verify_envelope(twice, trust)
    end

    test "an envelope signature is not a term signature", %{issuer: issuer} do
      envelope = Signer.sign_envelope(%{state: 1}, issuer)
      body = Map.delete(envelope, :signature)
      assert {:error, :bad_signature} = Signer.verify(body, envelope.signature, issuer.public)
    end
  end

  describe "modules" do
    setup do
      suffix = System.unique_integer([:positive])

      source = fn body ->
        "defmodule Tartarus.Security.SignerTest.Shipped#{suffix} do #{body} end"
      end

      [{module, beam}] = Code.compile_string(source.("def hi, do: :hi"))
      purge(module)

      [{^module, evil_beam}] = Code.compile_string(source.("def hi, do: :pwned"))
      purge(module)

      [{other, other_beam}] =
        Code.compile_string("defmodule Tartarus.Security.SignerTest.Other#{suffix} do end")

      purge(other)

      %{module: module, beam: beam, evil_beam: evil_beam, other: other, other_beam: other_beam}
    end

    test "good path: a signed module verifies", %{issuer: issuer, trust: trust} = ctx do
      sig = Signer.sign_module(ctx.module, ctx.beam, issuer)

      assert sig.module == ctx.module
      assert sig.md5 == :erlang.md5(ctx.beam)
      assert :ok = Signer.verify_module(ctx.module, ctx.beam, sig, trust)
    end

    test "tampered code is refused", %{issuer: issuer, trust: trust} = ctx do
      sig = Signer.sign_module(ctx.module, ctx.beam, issuer)

      assert {:error, :bad_signature} =
               Signer.verify_module(ctx.module, ctx.evil_beam, sig, trust)

      <<head::binary-size(100), byte, rest::binary>> = ctx.beam
      flipped = <<head::binary, Bitwise.bxor(byte, 1), rest::binary>>
      assert {:error, _} = Signer.verify_module(ctx.module, flipped, sig, trust)
    end

    test "a signature cannot be moved to another module", %{issuer: issuer, trust: trust} = ctx do
      sig = Signer.sign_module(ctx.module, ctx.beam, issuer)

      assert {:error, {:module_mismatch, expected, got}} =
               Signer.verify_module(ctx.other, ctx.beam, sig, trust)

      assert {expected, got} == {ctx.other, ctx.module}

      assert {:error, :bad_signature} =
               Signer.verify_module(ctx.other, ctx.other_beam, sig, trust)
    end

    test "code from an unknown issuer is refused", %{trust: trust} = ctx do
      mallory = Keys.generate()
      sig = Signer.sign_module(ctx.module, ctx.evil_beam, mallory)

      assert {:error, {:unknown_issuer, fp}} =
               Signer.verify_module(ctx.module, ctx.evil_beam, sig, trust)

      assert fp == Keys.fingerprint(mallory.public)
    end

    test "a malformed module signature gets an error, not a crash", %{trust: trust} = ctx do
      assert {:error, {:missing_field, :issuer}} =
               Signer.verify_module(ctx.module, ctx.beam, %{}, trust)

      assert {:error, {:invalid_module_signature, message}} =
               Signer.verify_module(ctx.module, ctx.beam, :nope, trust)

      assert message ==
               "expected a module name, a BEAM binary and a map with :issuer and :signature, " <>
                 "got: #{inspect(ctx.module)}, a binary, :nope"
    end

    test "a binary that is not BEAM is refused", %{issuer: issuer, trust: trust} = ctx do
      sig = Signer.sign_module(ctx.module, "not a beam", issuer)

      assert {:error, {:invalid_beam, module}} =
               Signer.verify_module(ctx.module, "not a beam", sig, trust)

      assert module == ctx.module
    end
  end

  describe "trust lists" do
    test "add, remove, member?, size", %{issuer: issuer} do
      other = Keys.generate()
      trust = TrustList.new() |> TrustList.add(issuer.public) |> TrustList.add(other.public)

      assert TrustList.size(trust) == 2
      assert TrustList.member?(trust, other.public)

      trust = TrustList.remove(trust, other.public)
      refute TrustList.member?(trust, other.public)
      assert TrustList.fingerprints(trust) == [Keys.fingerprint(issuer.public)]
    end

    test "check refuses unknown issuers before looking at the signature", %{issuer: issuer} do
      sig = Signer.sign(:term, issuer)
      fp = Keys.fingerprint(issuer.public)

      assert {:error, {:unknown_issuer, ^fp}} =
               TrustList.check(TrustList.new(), issuer.public, :term, sig)

      assert {:error, {:unknown_issuer, ":junk"}} =
               TrustList.check(TrustList.new(), :junk, :term, sig)
    end

    test "from_dir loads every .pub file" do
      dir = Path.join(System.tmp_dir!(), "tartarus_trust_#{System.unique_integer([:positive])}")
      on_exit(fn -> File.rm_rf!(dir) end)

      [alice, bob] = [Keys.generate(), Keys.generate()]
      :ok = Keys.save(alice, dir, "alice")
      :ok = Keys.save(bob, dir, "bob")
      File.write!(Path.join(dir, "README"), "ignored")

      assert {:ok, trust} = TrustList.from_dir(dir)
      assert TrustList.size(trust) == 2
      assert TrustList.member?(trust, alice.public) and TrustList.member?(trust, bob.public)

      File.write!(Path.join(dir, "broken.pub"), "xx")
      assert {:error, {:bad_key_size, path, 32, 2}} = TrustList.from_dir(dir)
      assert path == Path.join(dir, "broken.pub")

      assert {:error, {:file, _, :enoent}} = TrustList.from_dir(Path.join(dir, "missing"))
    end
  end

  defp purge(module) do
    :code.purge(module)
    :code.delete(module)
    :code.purge(module)
  end
end
