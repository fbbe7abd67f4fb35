defmodule TartarusArena.CameraPlugin do
  @moduledoc """
  A camera looking down on a shared arena, as a `Tartarus.Plugin` (the roadblock
  scenario's monitoring node): `Tartarus.Agent.read(:camera, :snapshot)` returns a PNG
  (binary) of what it sees.

  Options: `:arena` (a `TartarusArena.Server`, required); with `:pose` or `:robot`, a
  pinhole camera (`TartarusArena.Render.camera_png/2`: `:pose`, `:robot`, `:height`,
  `:pitch`, `:fov`, `:pixels`); otherwise a camera looking straight down
  (`TartarusArena.Render.png/2`: `:center`, `:view`, `:pixels`).
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
  def describe(s) do
    view =
      if Keyword.has_key?(s.view, :pose) or Keyword.has_key?(s.view, :robot),
        do: :pinhole,
        else: :overhead

    %{kind: :camera, reads: [:snapshot], writes: [], format: :png, view: view}
  end

  @impl true
  @doc "`:snapshot` (or nil): a PNG of the view."
  def read(arg, s) when arg in [nil, :snapshot] do
    world = TartarusArena.Server.world(s.arena)

    png =
      if Keyword.has_key?(s.view, :pose) or Keyword.has_key?(s.view, :robot),
        do: TartarusArena.Render.camera_png(world, s.view),
        else: TartarusArena.Render.png(world, s.view)

    {:ok, png, s}
  end

  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  @doc "Takes no writes."
  def write(arg, s), do: {:error, {:bad_argument, arg}, s}
end
