#!/usr/bin/env bash
# leveld's cost at a busy bus, against candump receiving the same frames in the same run.
#
#   tools/vcan-vm.sh tools/bus-cost.sh LEVELD_BINARY [SECONDS]
#
# For each bus load (500 kbit/s and 1 Mbit/s saturated with 8-byte frames: about 4000
# and 8000 frames/s), canplayer plays the drive of data/sim-multi-stop.log (the three
# configured messages, 250 frames/s) with unrelated frames filling the rest of the
# bus onto a vcan. `leveld run` and `candump -L` (writing its log to a tmpfs) receive
# it side by side; the CPU time each used while the traffic played comes from
# /proc/PID/stat (utime + stime), the peak RSS from VmHWM. Under an emulated VM the
# absolute figures are slow; the ratio to candump is what carries over to an ECU.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$(realpath "$1")
secs=${2:-20}
iface=vcanbus0
tmp=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null; ip link del "$iface" 2>/dev/null; rm -rf "$tmp"' EXIT

ip link add dev "$iface" type vcan
ip link set up "$iface"

sed -e "s|^input_interfaces = .*|input_interfaces = [\"$iface\"]|" \
    -e "s|^output_interface = .*|output_interface = \"$iface\"|" \
    -e "s|^dbc = .*|dbc = \"$PWD/dbc/leveld.dbc\"|" \
    -e "s|^path = \"/var/lib/leveld/state.json\"|path = \"$tmp/state.json\"\nstatus_path = \"\"|" \
    config/leveld.toml > "$tmp/leveld.toml"
grep -q "^path = \"$tmp/state.json\"" "$tmp/leveld.toml" || { echo "bus-cost: no state path to replace in config/leveld.toml" >&2; exit 1; }
"$bin" check-config --config "$tmp/leveld.toml" > /dev/null

# A candump -L log of SECONDS s at RATE frames/s: the drive's frames at their own times
# (from its start), unrelated 8-byte frames (IDs 0x100-0x17F) evenly in between.
make_log() {
  python3 - "$1" "$2" data/sim-multi-stop.log <<'PY'
import random, sys
rate, secs, drive = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
rnd = random.Random(7)
frames = []
t0 = None
with open(drive) as f:
    for line in f:
        ts, _, frame = line.split()
        t = float(ts[1:-1])
        t0 = t if t0 is None else t0
        if t - t0 >= secs:
            break
        frames.append((t - t0, frame))
fill = rate * secs - len(frames)
step = secs / fill
for k in range(int(fill)):
    frames.append((k * step, "%03X#%016X" % (0x100 + k % 0x80, rnd.getrandbits(64))))
frames.sort(key=lambda x: x[0])
for t, frame in frames:
    print("(%.6f) can0 %s" % (1000.0 + t, frame))
PY
}

cpu_ticks() { awk '{ print $14 + $15 }' "/proc/$1/stat"; }
hwm_kb() { awk '/^VmHWM/ { print $2 }' "/proc/$1/status"; }
hz=$(getconf CLK_TCK)

row() { printf '%-6s %7s %8s %9s %11s %11s %6s %9s %10s %7s %8s\n' "$@"; }
row bus frames frames/s "to leveld" "leveld cpu" "candump cpu" ratio "leveld" "candump" leveld candump
row "" "" "" "" "" "" "" "us/frame" "us/frame" "RSS MB" "RSS MB"
for load in "idle 0" "500k 4000" "1M 8000"; do
  set -- $load
  if [ "$2" = 0 ]; then : > "$tmp/bus.log"; else make_log "$2" "$secs" > "$tmp/bus.log"; fi
  frames=$(wc -l < "$tmp/bus.log")
  configured=$(grep -c ' can0 \(386\|3E0\|3E1\)#' "$tmp/bus.log" || true)
  LEVELD_LOG=warn "$bin" run --config "$tmp/leveld.toml" 2> "$tmp/leveld.err" &
  lp=$!
  candump -L "$iface" > "$tmp/candump.log" &
  cp=$!
  sleep 2
  kill -0 $lp || { cat "$tmp/leveld.err" >&2; exit 1; }
  l0=$(cpu_ticks $lp) c0=$(cpu_ticks $cp) w0=$(date +%s.%N)
  if [ "$frames" -gt 0 ]; then canplayer -I "$tmp/bus.log" "$iface=can0"; else sleep "$secs"; fi
  sleep 1
  l1=$(cpu_ticks $lp) c1=$(cpu_ticks $cp) w1=$(date +%s.%N)
  lr=$(hwm_kb $lp) cr=$(hwm_kb $cp)
  kill -TERM $lp $cp
  wait $lp 2>/dev/null || true
  wait $cp 2>/dev/null || true
  # candump also sees leveld's own LEVELING frames (3E8); the bus frames are the rest.
  got=$(grep -vc ' [^ ]* 3E8#' "$tmp/candump.log" || true)
  [ "$got" -ge $((frames * 99 / 100)) ] || echo "bus-cost: candump received $got of $frames frames" >&2
  awk -v b="$1" -v n="$frames" -v k="$configured" -v w="$w1" -v v="$w0" -v l=$((l1 - l0)) -v c=$((c1 - c0)) \
      -v hz="$hz" -v lr="$lr" -v cr="$cr" 'BEGIN {
    printf "%-6s %7d %8.0f %9d %9.2f s %9.2f s %6s %9s %10s %7.1f %8.1f\n", b, n, n / (w - v - 1), k, l / hz, c / hz,
      (n > 0 && c > 0 ? sprintf("%.2f", l / c) : "-"), (k > 0 ? sprintf("%.0f", 1e6 * l / hz / k) : "-"),
      (n > 0 ? sprintf("%.0f", 1e6 * c / hz / n) : "-"), lr / 1024, cr / 1024 }'
done
echo "(cpu: utime + stime over the ${secs} s the traffic played; ratio = leveld / candump on the"
echo "same bus; to leveld = frames of the configured messages, the only ones its receive filters"
echo "let through; us/frame = cpu per frame received, the idle cost included)"
