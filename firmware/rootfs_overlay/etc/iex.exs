# The IEx prompt on the Pi (ssh, or iex --remsh).
use Toolshed

IO.puts("""
Tartarus node #{node()}
  Tartarus.hosts()                          the host on this Pi
  Tartarus.plugins(TartarusFirmware.host()) its devices
  Tartarus.read_plugin(TartarusFirmware.host(), :beacon, :counts)
""")
