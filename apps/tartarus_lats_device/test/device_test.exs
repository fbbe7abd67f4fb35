defmodule TartarusLats.DeviceTest do
  # One LATS node on its own clock: the driver starts the database agent and drives it each
  # second; a Where am I released on the host answers for the tag its receiver hears.
  use ExUnit.Case, async: false

  defmodule Receiver do
    @moduledoc false
    # A BLE receiver that hears one tag at -61 dBm every second.
    @behaviour Tartarus.Plugin
    @impl true
    def init(opts), do: {:ok, Keyword.fetch!(opts, :tag)}
    @impl true
    def describe(_), do: %{kind: :ble, reads: [:scan]}
    @impl true
    def read({:scan, _t}, tag), do: {:ok, %{tag => -61}, tag}
    def read(arg, tag), do: {:error, {:bad_argument, arg}, tag}
    @impl true
    def write(arg, tag), do: {:error, {:bad_argument, arg}, tag}
  end

  @tag_id {"74278bdab64445208f0c720eaf059935", 1234, 1111}

  test "Where am I answers in the node's zone once its seconds have run" do
    name = :"lats_dev_#{System.unique_integer([:positive])}"
    {:ok, host} = Tartarus.start_host(name)
    :ok = Tartarus.attach_plugin(name, :beacon, {Receiver, tag: @tag_id})
    {:ok, device} = TartarusLats.Device.start_link(host: host, node: :hall, period_ms: 20)

    try do
      wait(fn -> TartarusLats.Device.second(device) >= 8 end)

      {:ok, id} =
        Tartarus.create_mobile_agent(
          name,
          TartarusLats.Query.WhereAmI,
          %{tag: @tag_id, label: nil, report: false, cloud: :per_node, repair: false},
          owner: self()
        )

      assert_receive {:tartarus_result, ^id, %{answer: {:in_zone, :hall}}}, 10_000
    after
      GenServer.stop(device)
      Tartarus.stop_host(name)
    end
  end

  defp wait(fun, tries \\ 200) do
    cond do
      fun.() -> :ok
      tries == 0 -> flunk("the node's seconds did not run")
      true -> Process.sleep(20) && wait(fun, tries - 1)
    end
  end
end
