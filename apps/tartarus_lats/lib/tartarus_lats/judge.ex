defmodule TartarusLats.Judge do
  @moduledoc """
  The judge of the thesis's comparison (§3.4.2-3.4.5): whether an answer to a query, from
  the agents or from the cloud, is correct against the world's ground truth
  (`TartarusLats.World.visited_path/2`), and how far a Trace's times are from the truth.
  Both designs are judged by the same rule (`correct?/4`); pure functions of the answer,
  the bearer's path and the release time.

  The trackers and the zone decision (`TartarusLats.Zone`) see a move a few seconds late
  and an exit is decided by a 15 s handshake timeout, so one rule judges settled and
  moving targets alike: an answer is correct when it is true of the bearer at some second
  of the 15 s before its release.
  """

  alias TartarusLats.World
  alias TartarusTools.Stats

  @lag 15

  @doc """
  Whether an answer to a query released at world second `t` is correct, given the
  bearer's ground-truth path (`TartarusLats.World.visited_path/2` at `t`). One definition
  for settled and moving targets: the answer must be true of the bearer at some second of
  the **lag window** `[t - #{@lag}, t]` (#{@lag} s: the motion vectors' handshake timeout,
  which bounds how late the trackers see a move or an exit):

    * `{:in_zone, z}` - the bearer was in `z` at some second of the window;
    * `:left_building` - the bearer was outside, after having been inside, at some second
      of the window;
    * `{:in_transit, z}` - the bearer was in `z` in the window and is not in `z` at `t`
      (it left `z` and the next zone has not been confirmed yet);
    * Trace `{:ok, %{path: p, status: s}}` - at some second `u` of the window, `p`'s zones
      are exactly the zones the bearer had entered by `u` (pass-through zones included)
      and `s` is `:present` if the bearer was inside at `u`, `:exited` if outside; an
      `:in_transit` status is right when, at `u`, the bearer had left the last zone of `p`.

  Anything else (`:not_found`, a wrong zone, a stale answer about an earlier place) is
  wrong. For a settled target (in its zone for 20 s, or out for 30 s) the window holds a
  single truth, so this is exact equality with the truth at `t`.

      iex> path = [%{zone: :p1, entered_at: 10, left_at: 50}, %{zone: :p2, entered_at: 50, left_at: nil}]
      iex> TartarusLats.Judge.correct?(:where_is, {:in_zone, :p1}, path, 60)
      true
      iex> TartarusLats.Judge.correct?(:where_is, {:in_zone, :p1}, path, 80)
      false
      iex> TartarusLats.Judge.correct?(:where_is, {:in_transit, :p1}, path, 60)
      true
  """
  @spec correct?(atom(), term(), [World.stay()], number()) :: boolean()
  def correct?(type, answer, path, t) do
    Enum.any?(max(t - @lag, 0)..t, &true_at?(type, answer, path, &1, t))
  end

  @doc "The lag window of `correct?/4`, in world seconds."
  @spec lag_window() :: pos_integer()
  def lag_window, do: @lag

  defp true_at?(:trace, {:ok, %{path: p, status: status}}, path, u, _t) do
    entered = Enum.filter(path, &(&1.entered_at <= u))

    Enum.map(p, & &1.node) == Enum.map(entered, & &1.zone) and entered != [] and
      case status do
        :present -> zone_at(path, u) not in [:outside, :not_entered]
        :exited -> zone_at(path, u) == :outside
        :in_transit -> List.last(entered).left_at != nil and List.last(entered).left_at <= u
        _ -> false
      end
  end

  defp true_at?(:trace, _answer, _path, _u, _t), do: false
  defp true_at?(_type, {:in_zone, z}, path, u, _t), do: zone_at(path, u) == z
  defp true_at?(_type, :left_building, path, u, _t), do: zone_at(path, u) == :outside

  defp true_at?(_type, {:in_transit, z}, path, u, t),
    do: zone_at(path, u) == z and zone_at(path, t) != z

  defp true_at?(_type, _answer, _path, _u, _t), do: false

  @doc """
  Where the bearer of ground-truth path `path` was at world second `u`: a zone,
  `:outside` (after having been inside), or `:not_entered`.

      iex> path = [%{zone: :p1, entered_at: 10, left_at: 50}, %{zone: :p2, entered_at: 50, left_at: 70}]
      iex> Enum.map([5, 10, 49, 50, 70], &TartarusLats.Judge.zone_at(path, &1))
      [:not_entered, :p1, :p1, :p2, :outside]
  """
  @spec zone_at([World.stay()], number()) :: term()
  def zone_at(path, u) do
    case Enum.find(path, &(&1.entered_at <= u and (&1.left_at == nil or u < &1.left_at))) do
      %{zone: z} -> z
      nil -> if Enum.any?(path, &(&1.entered_at <= u)), do: :outside, else: :not_entered
    end
  end

  @doc """
  How far a Trace answer's entry times are from the truth: the median absolute difference
  (world seconds) between each answered node's `arrived_at` and the true stay's
  `entered_at`, when the answer has as many stays as the truth; nil otherwise, and for
  other query types.

      iex> answer = {:ok, %{path: [%{node: :p1, arrived_at: 12}, %{node: :p2, arrived_at: 55}], status: :present}}
      iex> truth = %{path: [%{zone: :p1, entered_at: 10, left_at: 50}, %{zone: :p2, entered_at: 50, left_at: nil}]}
      iex> TartarusLats.Judge.time_error(:trace, answer, truth)
      2
      iex> TartarusLats.Judge.time_error(:where_is, {:in_zone, :p1}, {:in_zone, :p1})
      nil
  """
  @spec time_error(atom(), term(), term()) :: number() | nil
  def time_error(:trace, {:ok, %{path: path}}, %{path: truth})
      when length(path) == length(truth) do
    errors = Enum.zip_with(path, truth, fn p, t -> abs(p.arrived_at - t.entered_at) end)
    Stats.median(errors)
  end

  def time_error(_type, _answer, _truth), do: nil
end
