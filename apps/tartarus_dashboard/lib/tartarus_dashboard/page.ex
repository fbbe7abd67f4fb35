defmodule TartarusDashboard.Page do
  @moduledoc false
  # The page: plain HTML, CSS and JavaScript in one file (priv/index.html), read
  # at compile time and served from memory; no build step and nothing from the network.

  @path Path.expand("../../priv/index.html", __DIR__)
  @external_resource @path
  @html File.read!(@path)

  def html, do: @html
end
