defmodule Tartarus.Host.Persistence.ShippedCode do
  @moduledoc false
  # The code of a journaled agent that is not on the node's code path (shipped from another
  # node, or compiled at run time) is kept beside the journal, content-addressed: the BEAM
  # binary in `code/<md5 in hex>.beam` (written once, to a temporary file renamed into
  # place, keep/3), and a record {:code, module, md5} in the journal
  # (Tartarus.Host.Persistence writes it after the binary, before the record of the agent
  # that needs it; each module is saved once per run of the host, a ledger entry remembers
  # it). Replaying keeps the last md5 of each module; the compaction of opening keeps the
  # records of the modules a live agent or in-doubt copy needs
  # (Tartarus.Host.Persistence.Records.needed_code/1) and deletes the files of the others
  # (drop_unused/2: the last agent that needed them is gone; compactions while the host runs
  # keep every code record, so the ledger's memory of what was saved stays true). Opening
  # the journal loads each kept module whose md5 the node does not run already (load/2;
  # Tartarus.CodeCache.load/1 checks the binary's md5), before any agent is restored.

  @doc false
  # The md5 of the loaded `module` if its code must be kept beside the journal ({:ok, md5}),
  # or :none: it is on the node's code path, or not loaded (it cannot run here either).
  def shipped_md5(module) do
    with false <- on_code_path?(module),
         {:ok, md5} <- Tartarus.CodeCache.md5(module) do
      {:ok, md5}
    else
      _ -> :none
    end
  end

  defp on_code_path?(mod) do
    case :code.which(mod) do
      path when is_list(path) -> String.ends_with?(List.to_string(path), ".beam")
      _ -> false
    end
  end

  @doc false
  # Writes the binary of `module` (md5 `md5`) beside the journal at `journal_path` unless it
  # is there already: :ok, :none when there is no binary to keep, or
  # {:error, {:journal, reason}}.
  def keep(journal_path, module, md5) do
    case Tartarus.CodeCache.fetch_binary(module, md5) do
      {:ok, bin} -> write(journal_path, md5, bin)
      {:error, {:no_object_code, _}} -> :none
    end
  end

  defp write(journal_path, md5, bin) do
    file = code_path(journal_path, md5)
    tmp = file <> ".tmp"

    with false <- File.exists?(file),
         :ok <- File.mkdir_p(Path.dirname(file)),
         :ok <- File.write(tmp, bin),
         :ok <- File.rename(tmp, file) do
      :ok
    else
      true ->
        :ok

      {:error, reason} ->
        _ = File.rm(tmp)
        {:error, {:journal, reason}}
    end
  end

  defp code_path(journal_path, md5),
    do:
      Path.join([Path.dirname(journal_path), "code", Base.encode16(md5, case: :lower) <> ".beam"])

  @doc false
  # Loads the modules the journal kept (`code`, a replayed state's %{module => md5}) that
  # this node does not run in that version: [{module, error}] for those that could not be
  # loaded.
  def load(journal_path, code) do
    for {mod, md5} <- code,
        Tartarus.CodeCache.md5(mod) != {:ok, md5},
        result = load_module(journal_path, mod, md5),
        result != :ok,
        do: {mod, result}
  end

  defp load_module(journal_path, mod, md5) do
    with {:ok, bin} <- File.read(code_path(journal_path, md5)) do
      Tartarus.CodeCache.load([{mod, md5, bin}])
    end
  end

  @doc false
  # Deletes the kept binaries that `code` (the code records a compaction kept) does not
  # name.
  def drop_unused(journal_path, code) do
    dir = Path.join(Path.dirname(journal_path), "code")
    keep = MapSet.new(code, fn {_mod, md5} -> Base.encode16(md5, case: :lower) <> ".beam" end)

    case File.ls(dir) do
      {:ok, files} ->
        for f <- files,
            String.ends_with?(f, ".beam"),
            f not in keep,
            do: File.rm(Path.join(dir, f))

        :ok

      {:error, _} ->
        :ok
    end
  end
end
