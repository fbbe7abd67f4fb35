defmodule Tartarus.LayersTest do
  # scripts/check-closure.exs (run by scripts/check-layers): the release's and the
  # firmware's dependency closures hold no lab application or call, and the check fails,
  # naming the offence, when one does.
  use ExUnit.Case, async: false

  @moduletag :layers
  @moduletag timeout: 300_000

  defp check(args) do
    System.cmd("mix", ["run", "--no-start", "--no-compile", "scripts/check-closure.exs" | args],
      stderr_to_stdout: true
    )
  end

  test "the release and the firmware carry no lab (the dashboard is no lab); a release with the tooling app is refused" do
    {out, status} = check([])
    assert status == 0, out
    assert out =~ "the release (" and out =~ "tartarus_lats_device, tartarus_node)"
    # The dashboard is a device app (on the platform alone): in the release, not an offence.
    assert out =~ "tartarus, tartarus_dashboard, tartarus_lats_device"
    refute out =~ "tartarus_emu"

    {out, status} = check(["--release-apps", "tartarus_node,tartarus_lats"])
    assert status == 1, out
    assert out =~ "the release: application tartarus_emu is in it"
    assert out =~ "the release: application tartarus_tools is in it"
    refute out =~ "the firmware:"

    {out, status} = check(["--firmware-apps", "tartarus,tartarus_tools"])
    assert status == 1, out
    assert out =~ "the firmware: application tartarus_tools is in it"
  end
end
