defmodule TartarusTools.Provenance do
  @moduledoc """
  What made a result: the command line, the source tree's git commit (and whether it had
  uncommitted changes), the OTP and Elixir versions, the date and the machine. Every
  `summary.json`/`summary.md` carries it under `"provenance"` (`TartarusTools.Report`), and
  so does a task's `--json` summary (`TartarusTools.CLI.report/3`), so a figure can be
  traced to what made it.

      iex> p = TartarusTools.Provenance.collect()
      iex> Enum.sort(Map.keys(p))
      [:argv, :date, :elixir, :git_commit, :git_dirty, :machine, :otp]

  The command line is the one a mix task was started with (`record_command/2`, called by
  every task that `use TartarusTools.CLI`); outside a task it is the VM's `System.argv/0`.
  Git is asked with `git rev-parse HEAD` and `git status --porcelain`; where there is no git
  or no checkout the commit is `"unknown"` and the dirty flag `nil` (never an error).
  """

  @key {__MODULE__, :argv}

  @doc "Records the command line of the running mix task (`mix <task> <argv...>`)."
  @spec record_command(String.t(), [String.t()]) :: :ok
  def record_command(task, argv), do: put_argv(["mix", task | argv])

  @doc """
  Records `argv` as the command line of this VM's results: what a runner node started for
  a run is given, so that the summary it writes names the command that asked for it.
  """
  @spec put_argv([String.t()]) :: :ok
  def put_argv(argv) when is_list(argv), do: :persistent_term.put(@key, argv)

  @doc "The command line recorded (`record_command/2`, `put_argv/1`), else `System.argv/0`."
  @spec argv() :: [String.t()]
  def argv, do: :persistent_term.get(@key, System.argv())

  @doc """
  The provenance map: `argv` (list of strings), `git_commit` (hash or `"unknown"`),
  `git_dirty` (boolean, `nil` when unknown), `otp` and `elixir` (versions), `date` (UTC,
  ISO 8601, seconds), `machine` (`schedulers`, `logical_processors`, `memory_bytes` of
  the whole machine when known, `system`).
  """
  @spec collect() :: map()
  def collect do
    {commit, dirty} = git()

    %{
      argv: argv(),
      git_commit: commit,
      git_dirty: dirty,
      otp: otp_version(),
      elixir: System.version(),
      date: Tartarus.Clock.machine_system_time(:second) |> DateTime.from_unix!() |> DateTime.to_iso8601(),
      machine: %{
        schedulers: System.schedulers_online(),
        logical_processors: :erlang.system_info(:logical_processors_available) |> known(),
        memory_bytes: total_memory(),
        system: system()
      }
    }
  end

  defp known(:unknown), do: nil
  defp known(n), do: n

  defp otp_version do
    release = to_string(:erlang.system_info(:otp_release))
    file = Path.join([:code.root_dir(), "releases", release, "OTP_VERSION"])

    case File.read(file) do
      {:ok, text} -> String.trim(text)
      _ -> release
    end
  end

  defp git do
    with {:ok, commit} <- cmd(["rev-parse", "HEAD"]),
         {:ok, status} <- cmd(["status", "--porcelain", "--untracked-files=no"]) do
      {String.trim(commit), String.trim(status) != ""}
    else
      _ -> {"unknown", nil}
    end
  end

  defp cmd(args) do
    if System.find_executable("git") do
      case System.cmd("git", args, stderr_to_stdout: true) do
        {out, 0} -> {:ok, out}
        _ -> :error
      end
    else
      :error
    end
  rescue
    _ -> :error
  end

  # Total memory of the machine in bytes: /proc/meminfo where there is one, else nil.
  defp total_memory do
    with {:ok, text} <- File.read("/proc/meminfo"),
         [_, kb] <- Regex.run(~r/MemTotal:\s+(\d+) kB/, text) do
      String.to_integer(kb) * 1024
    else
      _ -> nil
    end
  end

  defp system do
    {family, name} = :os.type()
    "#{family}/#{name} #{:erlang.system_info(:system_architecture)}"
  end
end
