defmodule Tartarus.TestSupport.Tags do
  @moduledoc """
  The umbrella's test tags, and the one place that decides which of them a run excludes.
  Every `test_helper.exs` (each app's and the top-level one) starts ExUnit with
  `start/1`.

  Tags for what a test costs or needs:

  | tag | the test | runs |
  | --- | --- | --- |
  | `:peer` | starts real BEAM nodes (OTP's `:peer`; needs epmd) | by default |
  | `:long` | takes a minute or more (Table 6.2 over 10 seeds) | by default |
  | `:heavy` | takes many minutes or 100 nodes (the 100-peer scale test, the long protocol model run) | with `TARTARUS_TESTS=all` |
  | `:browser` | drives headless Chromium | when Chromium is on the PATH |
  | `:socat` | needs `socat` (a pseudo-terminal pair) | when socat is on the PATH |
  | `:release` | builds the release (`MIX_ENV=prod mix release`) and runs it | by default |
  | `:netns` | the network-namespace bed (root, `ip netns`; nodes from the built release) | when root and namespaces are available |
  | `:tmpfs` | mounts a small tmpfs (a disk that fills up: root, `mount`) | when a tmpfs can be mounted |
  | `:known_bug` | shows a bug or a target not met yet | never, unless asked (`--only known_bug`) |

  One environment variable chooses the set, `TARTARUS_TESTS`:

    * `default` (or unset): everything but `:heavy` (what `scripts/test` runs);
    * `quick`: also without `:peer`, `:long`, `:browser`, `:release` and `:netns` (what
      needs no other node, no browser, no release build and less than a minute);
    * `all`: `:heavy` too.

  `mix test --include TAG` runs an excluded tag anyway, `--only TAG` only it, and
  `--exclude TAG` leaves one out (e.g. `scripts/test --exclude browser`). Other tags
  (`:property`, `:overlay`, `:durable`, `:firmware`, `:tmp_dir`) only name what a test is
  about, for `--only`.
  """

  @levels %{
    "quick" => [:peer, :long, :heavy, :browser, :release, :netns],
    "default" => [:heavy],
    "all" => []
  }

  # A tag that needs a program is excluded when the program is missing.
  @needs [browser: "Chromium", socat: "socat", netns: "network namespaces", tmpfs: "tmpfs"]

  @doc """
  The tags excluded at `level` (`"quick"`, `"default"` or `"all"`) when the programs of
  `available` (a subset of `:browser`, `:socat`, `:netns` and `:tmpfs`) are installed.

      iex> Tartarus.TestSupport.Tags.excludes("default", [:browser, :socat, :netns, :tmpfs])
      [:heavy, :known_bug]
      iex> Tartarus.TestSupport.Tags.excludes("all", [:socat, :tmpfs])
      [:browser, :known_bug, :netns]
      iex> Tartarus.TestSupport.Tags.excludes("quick", [])
      [:browser, :heavy, :known_bug, :long, :netns, :peer, :release, :socat, :tmpfs]
  """
  @spec excludes(String.t(), [atom()]) :: [atom()]
  def excludes(level, available) do
    missing = for {tag, _} <- @needs, tag not in available, do: tag
    Enum.sort(Enum.uniq(Map.fetch!(@levels, level) ++ missing ++ [:known_bug]))
  end

  @doc """
  The level `TARTARUS_TESTS` asks for (`"default"` when unset or empty); raises on any other
  value.

      iex> Tartarus.TestSupport.Tags.level(nil)
      "default"
      iex> Tartarus.TestSupport.Tags.level("all")
      "all"
  """
  @spec level(String.t() | nil) :: String.t()
  def level(value) when value in [nil, ""], do: "default"
  def level(value) when is_map_key(@levels, value), do: value

  def level(value) do
    raise ArgumentError,
          "TARTARUS_TESTS must be one of #{Enum.join(Map.keys(@levels), ", ")}, got: #{inspect(value)}"
  end

  @doc """
  Starts ExUnit with `opts` (`ExUnit.start/1`'s), excluding what `excludes/2` says for
  `TARTARUS_TESTS` and the programs found on this machine, besides any `:exclude` in `opts`.
  Says why a tag that needs a program is left out.
  """
  @spec start(keyword()) :: :ok
  def start(opts \\ []) do
    level = level(System.get_env("TARTARUS_TESTS"))
    available = Enum.filter(Keyword.keys(@needs), &available?/1)

    for {tag, program} <- @needs, tag not in available, tag not in @levels[level] do
      IO.puts("Excluding #{inspect(tag)} tests: #{why_missing(tag, program)}")
    end

    for old <- ["TARTARUS_SLOW", "TARTARUS_SCALE"], System.get_env(old) do
      IO.puts("#{old} is not read any more: use TARTARUS_TESTS=all (or default, or quick)")
    end

    excluded = excludes(level, available)
    ExUnit.start(Keyword.update(opts, :exclude, excluded, &(&1 ++ excluded)))
  end

  # The dashboard's browser driver (in the tooling app) knows where Chromium is. The
  # platform app does not depend on it and has no browser test: where the driver is not
  # loaded there is nothing to exclude.
  defp available?(:browser) do
    browser = TartarusTools.Browser
    not Code.ensure_loaded?(browser) or apply(browser, :executable, []) != nil
  end

  defp available?(:socat), do: System.find_executable("socat") != nil
  defp available?(:netns), do: netns() == :ok
  defp available?(:tmpfs), do: tmpfs() == :ok

  defp why_missing(:netns, _), do: elem(netns(), 1)
  defp why_missing(:tmpfs, _), do: elem(tmpfs(), 1)
  defp why_missing(_tag, program), do: "no #{program} on the PATH (scripts/test installs it)"

  @doc """
  `:ok` when a small tmpfs can be mounted here (Linux, root, `mount -t tmpfs` works: checked
  by mounting one on a fresh temporary directory and unmounting it), else
  `{:error, reason}`. The full-disk tests fill one up.
  """
  @spec tmpfs() :: :ok | {:error, String.t()}
  def tmpfs do
    dir = Path.join(System.tmp_dir!(), "tt-tmpfs-probe-#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)

    try do
      case mount_tmpfs(dir, "16k") do
        :ok ->
          unmount(dir)
          :ok

        {:error, why} ->
          {:error, "cannot mount a tmpfs (#{why}); the full-disk tests need root"}
      end
    after
      File.rmdir(dir)
    end
  end

  @doc "Mounts a tmpfs of `size` (e.g. `\"64k\"`) on `dir`: `:ok` or `{:error, output}`."
  @spec mount_tmpfs(Path.t(), String.t()) :: :ok | {:error, String.t()}
  def mount_tmpfs(dir, size) do
    case System.find_executable("mount") &&
           System.cmd("mount", ["-t", "tmpfs", "-o", "size=#{size}", "tmpfs", dir],
             stderr_to_stdout: true
           ) do
      {_, 0} -> :ok
      {out, _} -> {:error, String.trim(out)}
      nil -> {:error, "no mount on the PATH"}
    end
  end

  @doc "Gives the tmpfs on `dir` a new size (`mount -o remount`)."
  @spec resize_tmpfs(Path.t(), String.t()) :: :ok
  def resize_tmpfs(dir, size) do
    {_, 0} = System.cmd("mount", ["-o", "remount,size=#{size}", dir], stderr_to_stdout: true)
    :ok
  end

  @doc "Unmounts `dir`."
  @spec unmount(Path.t()) :: :ok
  def unmount(dir) do
    _ = System.cmd("umount", [dir], stderr_to_stdout: true)
    :ok
  end

  @doc """
  `:ok` when this machine can run the network-namespace bed (Linux, root, `ip`, and `ip
  netns add` works: checked by adding and deleting a namespace `tt29-probe-<n>`), else
  `{:error, reason}`. `TARTARUS_NETNS=off` turns the bed off.
  """
  @spec netns() :: :ok | {:error, String.t()}
  def netns do
    cond do
      System.get_env("TARTARUS_NETNS") == "off" ->
        {:error, "TARTARUS_NETNS=off"}

      :os.type() != {:unix, :linux} ->
        {:error, "not Linux"}

      System.cmd("id", ["-u"]) |> elem(0) |> String.trim() != "0" ->
        {:error, "not root (network namespaces need root)"}

      System.find_executable("ip") == nil ->
        {:error, "no `ip` (iproute2) on the PATH"}

      true ->
        probe = "tt29-probe-#{System.unique_integer([:positive])}"

        case System.cmd("ip", ["netns", "add", probe], stderr_to_stdout: true) do
          {_, 0} ->
            System.cmd("ip", ["netns", "del", probe], stderr_to_stdout: true)
            :ok

          {out, _} ->
            {:error, "`ip netns add` failed: #{String.trim(out)}"}
        end
    end
  end
end
