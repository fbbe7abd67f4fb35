defmodule TartarusNode.EnvSh do
  @moduledoc """
  The release's `env.sh` (`rel/env.sh.eex`) asks this module, in a VM of its own started
  before the node's, what the command it runs needs: `main/0` reads the node's file
  (`TartarusNode.Config`) and prints shell assignments, or one line and status 1.
  """

  alias TartarusNode.Config

  @doc """
  What the release's `env.sh` runs (in a VM of its own, before the node's): reads `path/0`
  and prints the shell assignments, or prints the one error line on stderr and halts with
  status 1.

  For the commands that start the node, it writes the node's TLS option file into
  `TARTARUS_TMP` (when `tls:` is set) and prints `TartarusNode.Config.shell/3`. For the operator's commands
  (`remote`, `rpc`, `stop`, `restart`, `pid`: `RELEASE_COMMAND`) on a TLS node it checks the
  operator's certificate and prints the assignments of `TartarusNode.Operator.shell/3`,
  which `env.sh` uses to run the command under the operator's name; a refusal is one line
  naming the cause (`TartarusNode.Operator.check/2`).
  """
  @spec main() :: no_return()
  def main do
    path = Config.path()
    command = System.get_env("RELEASE_COMMAND")
    client? = TartarusNode.Operator.command?(command)
    tmp = System.get_env("TARTARUS_TMP") || System.tmp_dir!()

    # Only the commands that start the node need its devices there (an unplugged adapter
    # must not lock the operator out, nor `eval`).
    devices = if command in ~w(start start_iex daemon daemon_iex), do: :present, else: :any

    with {:ok, c} <- Config.read(path, devices: devices),
         {:ok, text} <- shell_text(c, command, client?, tmp) do
      IO.write(text)
      System.halt(0)
    else
      {:error, line} ->
        IO.puts(:stderr, line)
        System.halt(1)
    end
  end

  defp shell_text(%{tls: tls} = c, command, true, tmp) when tls != nil do
    with {:ok, op} <- TartarusNode.Operator.check(c, tmp) do
      {:ok, TartarusNode.Operator.shell(c, op, command)}
    end
  rescue
    e in File.Error -> {:error, "tartarus: #{command}: #{Exception.message(e)}"}
  end

  defp shell_text(c, _command, true, _tmp), do: {:ok, Config.shell(c, "", :client)}

  defp shell_text(c, _command, false, tmp) do
    optfile = Path.join(tmp, "ssl_dist.conf")

    if c.tls do
      File.mkdir_p!(Path.dirname(optfile))
      text = :io_lib.format(~c"~tp.~n", [Config.optfile_terms(c)])
      File.write!(optfile, ["%% ssl_dist options for #{c.node}; written at boot.\n", text])
    end

    {:ok, Config.shell(c, optfile)}
  rescue
    e in File.Error -> {:error, "tartarus: cannot write the TLS option file: #{Exception.message(e)}"}
  end
end
