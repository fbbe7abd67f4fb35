defmodule Tartarus.FacadeTest do
  # The facade is a documented door: every public function has a doc and a spec, and the
  # helpers other nodes call (`Tartarus.Host.OnNode`) are not part of it.
  use ExUnit.Case, async: true

  test "every public function of Tartarus has a @doc and a @spec; no local_* helpers" do
    {:docs_v1, _, _, _, _, _, docs} = Code.fetch_docs(Tartarus)
    {:ok, specs} = Code.Typespec.fetch_specs(Tartarus)
    specced = for {{name, arity}, _} <- specs, do: {name, arity}

    documented =
      for {{:function, name, arity}, _, _, doc, _} <- docs,
          doc not in [:hidden, :none],
          do: {name, arity}

    exported = Tartarus.__info__(:functions)
    assert exported != []

    for {name, arity} <- exported do
      refute String.starts_with?(Atom.to_string(name), "local_"), "#{name}/#{arity}"
      # Functions with default arguments are documented and specced at their full arity.
      full = Enum.max(for {^name, a} <- exported, do: a)
      assert {name, full} in documented, "#{name}/#{full} has no @doc"
      assert {name, full} in specced, "#{name}/#{full} has no @spec"
    end
  end

  test "on-node reads answer for hosts of other nodes and unknown hosts alike" do
    assert Tartarus.status(:no_such_host) == {:error, {:unknown_host, {:no_such_host, node()}}}

    assert Tartarus.agents({:h, :nonode@nowhere}) ==
             {:error, {:unknown_host, {:h, :nonode@nowhere}}}

    assert Tartarus.hop_times(3) == {:error, {:unknown_host, 3}}
  end
end
