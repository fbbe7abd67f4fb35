defmodule Tartarus.Security.KeysTest do
  use ExUnit.Case, async: true

  alias Tartarus.Security.Keys

  doctest Keys

  setup do
    dir = Path.join(System.tmp_dir!(), "tartarus_keys_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    %{dir: dir}
  end

  test "save then load gives back the same keys, with a private secret file", %{dir: dir} do
    keys = Keys.generate()
    assert :ok = Keys.save(keys, dir)
    assert {:ok, ^keys} = Keys.load(dir)

    assert File.stat!(Path.join(dir, "issuer.key")).mode |> Bitwise.band(0o777) == 0o600
    assert File.read!(Path.join(dir, "issuer.pub")) == keys.public
    assert {:ok, pub} = Keys.load_public(Path.join(dir, "issuer.pub"))
    assert pub == keys.public
  end

  test "keys can be saved under a name", %{dir: dir} do
    keys = Keys.generate()
    :ok = Keys.save!(keys, dir, "alice")
    assert Keys.load!(dir, "alice") == keys
    assert {:error, {:file, path, :enoent}} = Keys.load(dir)
    assert path == Path.join(dir, "issuer.key")
  end

  test "load refuses a secret key readable by others", %{dir: dir} do
    :ok = Keys.save(Keys.generate(), dir)
    path = Path.join(dir, "issuer.key")
    File.chmod!(path, 0o644)

    assert {:error, {:insecure_permissions, ^path, _mode}} = Keys.load(dir)

    assert_raise ArgumentError,
                 "insecure key file #{path}: expected mode 0600 (no access for group or others), got: 0644",
                 fn -> Keys.load!(dir) end
  end

  test "load refuses a key file of the wrong size", %{dir: dir} do
    :ok = Keys.save(Keys.generate(), dir)
    pub = Path.join(dir, "issuer.pub")
    File.write!(pub, "short")

    assert {:error, {:bad_key_size, ^pub, 32, 5}} = Keys.load(dir)
  end

  test "load refuses a public key that belongs to another secret key", %{dir: dir} do
    :ok = Keys.save(Keys.generate(), dir)
    File.write!(Path.join(dir, "issuer.pub"), Keys.generate().public)

    assert {:error, {:key_mismatch, _}} = Keys.load(dir)
  end

  test "fingerprint names what it expected and what arrived" do
    assert_raise ArgumentError,
                 "expected an Ed25519 public key (32 bytes), got: a binary of 3 bytes",
                 fn ->
                   Keys.fingerprint("abc")
                 end

    assert_raise ArgumentError, "expected an Ed25519 public key (32 bytes), got: :nope", fn ->
      Keys.fingerprint(:nope)
    end
  end
end
