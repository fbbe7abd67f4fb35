defmodule DiagTmpTest do
  use Tartarus.HostCase, async: false

  test "diag" do
    for round <- 1..20 do
      [a, b] = line!(2)
      id = agent!(a)
      ref = {id, a}
      mover = Task.async(fn -> for i <- 1..30, do: Tartarus.move(ref, if(rem(i, 2) == 1, do: b, else: a)) end)
      tasks = for _ <- 1..4, do: Task.async(fn -> for _ <- 1..100, do: Tartarus.post(ref, :inc) end)
      raw = tasks |> Enum.map(&Task.await(&1, 20_000))
      posts = raw |> Enum.map(&Enum.frequencies/1)
      moves = Task.await(mover, 20_000)
      if Enum.any?(posts, &Map.has_key?(&1, {:error, :not_found})) do
        IO.inspect({round, posts, Enum.frequencies(moves)}, label: "posts")
        IO.inspect(Enum.map(raw, fn l -> Enum.map(l, fn :ok -> 1; {:error, :not_found} -> 0; _ -> 9 end) |> Enum.join() end), label: "seq")
        IO.inspect(Enum.with_index(moves) |> Enum.reject(&(elem(&1, 0) == :ok)), label: "failed moves")
        IO.inspect({Tartarus.agents(a), Tartarus.agents(b), Tartarus.whereis(ref), Tartarus.post(ref, :inc)}, label: "after")
      end
    end
  end
end
