# A Raspberry Pi (MIX_TARGET=rpi0 | rpi3 | rpi4).
import Config

# Boot: start the runtime and networking first, then the firmware.
config :shoehorn, init: [:nerves_runtime, :nerves_pack]

# Hostnames are tartarus-<serial>, e.g. tartarus-1a2b; the node is tartarus@tartarus-1a2b.local.
config :nerves, :erlinit, hostname_pattern: "tartarus-%s"

config :nerves, :firmware, rootfs_overlay: "rootfs_overlay"

# SSH (firmware updates with `mix upload`, a shell): the keys of the user who builds.
keys =
  ["id_rsa.pub", "id_ecdsa.pub", "id_ed25519.pub"]
  |> Enum.map(&Path.join([System.user_home!(), ".ssh", &1]))
  |> Enum.filter(&File.exists?/1)

if keys == [],
  do:
    Mix.raise("""
    No SSH public keys found in ~/.ssh. An ssh key is required to log in to the Pi and to
    upload new firmware (`mix upload`).
    """)

config :nerves_ssh, authorized_keys: Enum.map(keys, &File.read!/1)

# Wi-Fi from the environment of the build: TARTARUS_WIFI_SSID, TARTARUS_WIFI_PSK and
# TARTARUS_WIFI_COUNTRY (the regulatory domain, e.g. "FR"; "00" is the world-safe default).
# Without an SSID the Pi uses Ethernet and USB gadget networking only.
wifi =
  case System.get_env("TARTARUS_WIFI_SSID") do
    ssid when is_binary(ssid) and ssid != "" ->
      [
        {"wlan0",
         %{
           type: VintageNetWiFi,
           vintage_net_wifi: %{
             networks: [
               %{key_mgmt: :wpa_psk, ssid: ssid, psk: System.get_env("TARTARUS_WIFI_PSK", "")}
             ]
           },
           ipv4: %{method: :dhcp}
         }}
      ]

    _ ->
      []
  end

config :vintage_net,
  regulatory_domain: System.get_env("TARTARUS_WIFI_COUNTRY", "00"),
  config:
    [
      {"usb0", %{type: VintageNetDirect}},
      {"eth0", %{type: VintageNetEthernet, ipv4: %{method: :dhcp}}}
    ] ++ wifi

# mDNS: the Pi answers to <hostname>.local and, until it has certificates, tartarus.local
# too is worth trying (every Pi of this firmware answers to it: with one fresh Pi on the
# network, `ssh tartarus.local` reaches it and tells its node name; see docs/devices.md).
# It advertises ssh and epmd.
config :mdns_lite,
  hosts: [:hostname, "tartarus"],
  ttl: 120,
  services: [
    %{protocol: "ssh", transport: "tcp", port: 22},
    %{protocol: "sftp-ssh", transport: "tcp", port: 22},
    %{protocol: "epmd", transport: "tcp", port: 4369}
  ]

# The node: distribution over TLS (rel/vm.args.eex names the option file this writes),
# certificates and trusted issuers read from /data (see docs/devices.md), the host's durable
# agents under /data too, and the devices of this Pi.
#
# The UART on GPIO 14/15 is ttyS0 (the mini UART) under the Pi 4's Nerves system, ttyAMA0
# under the Pi 0's and 3's. Neighbours: the host names and nodes of the other Pis this one
# links to at boot, from TARTARUS_NEIGHBOURS at build time ("pi2=tartarus@tartarus-3c4d.local,...").
uart = if Mix.target() == :rpi4, do: "ttyS0", else: "ttyAMA0"

neighbours =
  for item <- String.split(System.get_env("TARTARUS_NEIGHBOURS", ""), ",", trim: true) do
    case String.split(item, "=", parts: 2) do
      [host, node] ->
        {String.to_atom(String.trim(host)), String.to_atom(String.trim(node))}

      _ ->
        Mix.raise("TARTARUS_NEIGHBOURS: expected host=node items, got: #{item}")
    end
  end

config :tartarus_firmware,
  distribution: true,
  node_basename: "tartarus",
  data: "/data/tartarus",
  neighbours: neighbours,
  # LATS on this Pi: its database agent, driven every second (Where am I? answers here).
  services: [{TartarusLats.Device, []}],
  plugins: [
    # An HM-10 on the Pi's UART: a LATS node's BLE receiver.
    beacon: {TartarusFirmware.HM10, device: uart, speed: 9600},
    # A status LED and a push button.
    io: {TartarusFirmware.GPIO, pins: [led: {17, :output}, button: {27, :input}]}
  ]
