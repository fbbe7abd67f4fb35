defmodule TartarusDashboard.Panel do
  @moduledoc """
  A panel an application adds to the dashboard: a titled table, and buttons that act.
  The dashboard is given `panels: [{module, arg}]`; the page shows each panel's table below
  the graph, refreshed every few seconds (`GET /api/panels`), and its buttons post to
  `POST /api/panels/NAME/ACTION` (with the token).

  A panel's table cells are JSON values (strings, numbers, booleans, nil); a cell that
  names a host or an agent id is shown as a link to its detail. A panel may also show one
  picture (`:image`, e.g. a camera's snapshot): `%{type: "image/png", data: binary}`
  (PNG, JPEG, GIF or SVG), served inline with the panel (keep it small: the page fetches
  the panels every few seconds). An application that shows
  where its agents are writes, for instance:

      defmodule MyApp.Panel do
        @behaviour TartarusDashboard.Panel
        def name(_), do: "bearers"
        def render(net) do
          %{title: "Tag bearers", columns: ["tag", "host"], rows: MyApp.bearers(net), actions: []}
        end
        def act(_net, _action, _params), do: {:error, :unknown_action}
      end
  """

  @typedoc "A button: the action's name, its label, and the JSON params it posts."
  @type action :: %{action: String.t(), label: String.t(), params: map()}

  @typedoc "A picture: its media type and its bytes; `alt` describes it."
  @type image :: %{
          required(:type) => String.t(),
          required(:data) => binary(),
          optional(:alt) => String.t()
        }

  @typedoc "What a panel shows."
  @type view :: %{
          required(:title) => String.t(),
          required(:columns) => [String.t()],
          required(:rows) => [[term()]],
          optional(:actions) => [action()],
          optional(:text) => String.t(),
          optional(:image) => image() | nil
        }

  @image_types ~w(image/png image/jpeg image/gif image/svg+xml)

  @doc """
  A panel's picture as the page shows it: a `data:` URL, or nil (no picture, or a type
  the page does not show).

      iex> TartarusDashboard.Panel.data_url(%{type: "image/png", data: <<1, 2, 3>>})
      "data:image/png;base64,AQID"
      iex> TartarusDashboard.Panel.data_url(%{type: "text/html", data: "<b>"})
      nil
      iex> TartarusDashboard.Panel.data_url(nil)
      nil
  """
  @spec data_url(image() | nil) :: String.t() | nil
  def data_url(%{type: type, data: data}) when type in @image_types and is_binary(data),
    do: "data:" <> type <> ";base64," <> Base.encode64(data)

  def data_url(_), do: nil

  @doc """
  Reads `key` from the ETS table a run publishes itself into for its panel (the panel's
  `arg`): the objects, or `:gone` once the table is deleted (the run is over), so a page
  refreshed after the run says so instead of failing.

      iex> t = :ets.new(:panel_doc, [:public])
      iex> :ets.insert(t, {:run, 1})
      iex> TartarusDashboard.Panel.lookup(t, :run)
      [{:run, 1}]
      iex> :ets.delete(t)
      iex> TartarusDashboard.Panel.lookup(t, :run)
      :gone
  """
  @spec lookup(:ets.tid() | atom(), term()) :: [tuple()] | :gone
  def lookup(table, key) do
    :ets.lookup(table, key)
  rescue
    ArgumentError -> :gone
  end

  @doc """
  What a run does to publish itself for its panel: `fun.(table)` (an insert, an update, a
  delete), or nothing when there is no table (no dashboard) or it is gone. The run never
  depends on the page.

      iex> t = :ets.new(:panel_doc, [:public])
      iex> TartarusDashboard.Panel.publish(t, &:ets.insert(&1, {:round, 3}))
      :ok
      iex> TartarusDashboard.Panel.lookup(t, :round)
      [{:round, 3}]
      iex> TartarusDashboard.Panel.publish(nil, &:ets.insert(&1, {:round, 4}))
      :ok
  """
  @spec publish(:ets.tid() | atom() | nil, (:ets.tid() | atom() -> term())) :: :ok
  def publish(nil, _fun), do: :ok

  def publish(table, fun) do
    fun.(table)
    :ok
  rescue
    ArgumentError -> :ok
  end

  @doc "The panel's name in URLs (letters, digits, `_` and `-`)."
  @callback name(arg :: term()) :: String.t()

  @doc "What the panel shows now."
  @callback render(arg :: term()) :: view()

  @doc """
  Carries out one of the panel's actions with the JSON params the page posted. Returns
  `{:ok, result}` (a JSON value shown to the user) or `{:error, reason}`.
  """
  @callback act(arg :: term(), action :: String.t(), params :: map()) ::
              {:ok, term()} | {:error, term()}
end
