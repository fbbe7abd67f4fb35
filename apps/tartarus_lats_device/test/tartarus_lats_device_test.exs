defmodule TartarusLatsDeviceTest do
  # The device side of LATS stands on the platform alone (what a Pi's release or firmware
  # carries), and says which BLE receiver a node's {:ble, device} plugin uses.
  use ExUnit.Case, async: true

  test "depends on the platform alone and names no lab module" do
    apps = Application.spec(:tartarus_lats_device, :applications)
    assert :tartarus in apps
    refute Enum.any?(apps, &(&1 in [:tartarus_tools, :tartarus_emu, :tartarus_lats]))

    for m <- Application.spec(:tartarus_lats_device, :modules) do
      refute inspect(m) =~ ~r/^(TartarusEmu|TartarusTools)/, inspect(m)
    end
  end

  test "provides the BLE receiver that {:ble, device} plugins use" do
    assert Application.get_env(:tartarus_lats_device, :tartarus_ble_plugin) ==
             {TartarusLats.HM10.Receiver, :plugin}

    assert Tartarus.Plugin.Shorthand.ble_receiver() ==
             {:ok, {TartarusLats.HM10.Receiver, :plugin}}
  end
end
