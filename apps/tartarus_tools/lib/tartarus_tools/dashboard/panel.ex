defmodule TartarusTools.Dashboard.Panel do
  @moduledoc """
  A panel an application adds to the dashboard: a titled table, and buttons that act.
  The dashboard is given `panels: [{module, arg}]`; the page shows each panel's table below
  the graph, refreshed every few seconds (`GET /api/panels`), and its buttons post to
  `POST /api/panels/NAME/ACTION` (with the token).

  A panel's table cells are JSON values (strings, numbers, booleans, nil); a cell that
  names a host or an agent id is shown as a link to its detail. An application that shows
  where its agents are writes, for instance:

      defmodule MyApp.Panel do
        @behaviour TartarusTools.Dashboard.Panel
        def name(_), do: "bearers"
        def render(net) do
          %{title: "Tag bearers", columns: ["tag", "host"], rows: MyApp.bearers(net), actions: []}
        end
        def act(_net, _action, _params), do: {:error, :unknown_action}
      end
  """

  @typedoc "A button: the action's name, its label, and the JSON params it posts."
  @type action :: %{action: String.t(), label: String.t(), params: map()}

  @typedoc "What a panel shows."
  @type view :: %{
          required(:title) => String.t(),
          required(:columns) => [String.t()],
          required(:rows) => [[term()]],
          optional(:actions) => [action()],
          optional(:text) => String.t()
        }

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
