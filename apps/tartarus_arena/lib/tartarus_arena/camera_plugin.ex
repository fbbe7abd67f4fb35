defmodule TartarusArena.CameraPlugin do
  @moduledoc """
  A camera looking down on a shared arena, as a `Tartarus.Plugin` (the roadblock
  scenario's monitoring node): `Tartarus.Agent.read(:camera, :snapshot)` returns a PNG
  (binary) of the part of the arena it watches, drawn by `TartarusArena.Render.png/2`.

  Options: `:arena` (a `TartarusArena.Server`, required) and the view options of
  `TartarusArena.Render.png/2` (`:center`, `:view`, `:pixels`).
  """
  @behaviour Tartarus.Plugin

  @impl true
  @doc "Keeps the arena and the view."
  def init(opts) do
    case Keyword.get(opts, :arena) do
      nil -> {:error, {:bad_option, :arena, "required"}}
      arena -> {:ok, %{arena: arena, view: Keyword.delete(opts, :arena)}}
    end
  end

  @impl true
  @doc "A camera: reads `:snapshot`."
  def describe(_s), do: %{kind: :camera, reads: [:snapshot], writes: [], format: :png}

  @impl true
  @doc "`:snapshot` (or nil): a PNG of the view."
  def read(arg, s) when arg in [nil, :snapshot],
    do: {:ok, TartarusArena.Render.png(TartarusArena.Server.world(s.arena), s.view), s}

  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  @doc "Takes no writes."
  def write(arg, s), do: {:error, {:bad_argument, arg}, s}
end
