# The serial end-to-end test needs socat (scripts/test installs it).
exclude =
  if System.find_executable("socat") do
    []
  else
    IO.puts("socat is not installed: the :socat tests are excluded (scripts/test installs it)")
    [:socat]
  end

ExUnit.start(exclude: exclude)
