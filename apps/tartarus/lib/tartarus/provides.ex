defmodule Tartarus.Provides do
  @moduledoc """
  What the applications of a node provide to the platform, said in their application
  environment (their `mix.exs`), so the platform and the release name no application:

    * `tartarus_ble_plugin: {module, function}`: the BLE receiver of `{:ble, device}`
      plugins (`Tartarus.Plugin.Shorthand`; LATS's device app provides the HM-10's);
    * `tartarus_dashboard: module`: the web dashboard a node's `dashboard:` setting starts
      (`module.start/1`, `module.banner/1`; the dashboard app provides it).

  `find/1` reads the environments of the applications on the code path, loaded or not
  (from their `.app` files: nothing is loaded or started), so the answer is the same in a
  running node, under `mix`, and in the short VM that checks a release's configuration
  before the node boots (started without the release's `sys.config`).
  """

  @doc """
  The applications whose environment has `key`, with the value, sorted by application.

      iex> Tartarus.Provides.find(:tartarus_no_such_key_41)
      []
  """
  @spec find(atom()) :: [{atom(), term()}]
  def find(key) when is_atom(key) do
    for {app, env} <- app_envs(), Keyword.has_key?(env, key), do: {app, env[key]}
  end

  defp app_envs do
    loaded = for {app, _, _} <- Application.loaded_applications(), into: %{}, do: {app, nil}

    from_files =
      for dir <- :code.get_path(),
          file <- Path.wildcard(Path.join(List.to_string(dir), "*.app")),
          app = file |> Path.basename(".app") |> String.to_atom(),
          not Map.has_key?(loaded, app),
          {:ok, [{:application, ^app, props}]} <- [:file.consult(file)],
          do: {app, Keyword.get(props, :env, [])}

    Enum.sort(for({app, _} <- loaded, do: {app, Application.get_all_env(app)}) ++ from_files)
  end
end
