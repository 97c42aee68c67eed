#!/usr/bin/env bash
# Crash soak: `leveld run` killed with SIGKILL at random moments while a drive plays
# on a vcan, then restarted, over and over. After every kill the state file must be
# readable by leveld itself (or absent before the first save), the calibration file
# unchanged, and the saved window count one of the last two the daemon sent.
#
#   tools/vcan-vm.sh tools/soak.sh LEVELD DRIVE.log [CYCLES=1000] [LANES=4]
#
# LANES daemons run side by side, each on its own vcan with its own files, to get
# through the cycles faster. Each cycle plays the 13.5 s up to 1.5 s past one accepted
# window of the drive (so that saves happen) and kills the daemon anywhere in it (a
# third of the cycles) or in the 2.5 s around the window's save.
set -euo pipefail
# The whole script is one block, read before any of it runs: editing this file while
# a soak runs cannot change what the running soak does.
{
bin=$(realpath "$1")
drive=$(realpath "$2")
cycles=${3:-1000}
lanes=${4:-4}
root=$(cd "$(dirname "$0")/.." && pwd)
work=${TMPDIR:-/tmp}/leveld-soak
rm -rf "$work" && mkdir -p "$work"
# Run a private copy: a rebuild of the binary on the host while the soak runs would
# change the file under running daemons (they crash on the next page they load).
cp "$bin" "$work/leveld" && bin="$work/leveld"

# The drive's accepted windows, and a slice of the log from 12 s before each (a stop
# long enough to settle, then the drive-off) to 1.5 s after.
"$bin" replay "$drive" --format json 2>/dev/null | python3 -c '
import json, sys
for line in sys.stdin:
    e = json.loads(line)
    if e.get("event") == "window_accepted":
        print(e["window"]["t_s"])
' > "$work/windows"
n_slices=0
while read -r t; do
  awk -v a="$t" '{ s = substr($1, 2, length($1) - 2) + 0; if (s >= a - 12 && s < a + 1.5) print }' "$drive" > "$work/slice-$n_slices.log"
  n_slices=$((n_slices + 1))
done < "$work/windows"
[ "$n_slices" -gt 0 ] || { echo "soak: no accepted window in $drive" >&2; exit 1; }

lane() {
  local l=$1 n=$2 dir="$work/lane$1" iface="soak$1"
  mkdir -p "$dir"
  ip link add dev "$iface" type vcan && ip link set up "$iface"
  sed -e "s|input_interfaces = .*|input_interfaces = [\"$iface\"]|" \
      -e "s|output_interface = .*|output_interface = \"$iface\"|" \
      -e "s|^path = .*|path = \"$dir/state.json\"|" \
      -e "s|^calibration_path = .*|calibration_path = \"$dir/calibration.json\"\nstatus_path = \"\"|" \
      -e "s|^dbc = .*|dbc = \"$root/dbc/leveld.dbc\"|" \
      "$root/config/leveld.toml" > "$dir/leveld.toml"
  printf '{"format":1,"reference_pitch_deg":0.5,"settled_s":30.0,"written_unix_s":0.0}\n' > "$dir/calibration.json"
  local cal_sum saved=0 best=0 unreadable=0 backwards=0 saves=0
  cal_sum=$(sha256sum < "$dir/calibration.json")
  for i in $(seq 1 "$n"); do
    local slice=$((RANDOM % n_slices))
    # A third of the kills anywhere in the slice, the rest around the window's save.
    local kill_ms
    if [ $((RANDOM % 3)) -eq 0 ]; then
      kill_ms=$((50 + RANDOM % 13450))
    else
      kill_ms=$((11000 + RANDOM % 2500))
    fi
    candump -L "$iface,3E8:7FF" > "$dir/out.log" &
    local dump=$!
    "$bin" run --config "$dir/leveld.toml" 2>>"$dir/daemon.log" &
    local pid=$!
    canplayer -I "$work/slice-$slice.log" "$iface=can0" &
    local player=$!
    sleep "$(printf '%d.%03d' $((kill_ms / 1000)) $((kill_ms % 1000)))"
    kill -9 "$pid" 2>/dev/null || true
    kill "$player" 2>/dev/null || true
    wait "$pid" "$player" 2>/dev/null || true
    kill "$dump" 2>/dev/null || true
    wait "$dump" 2>/dev/null || true
    # EstimateCount (bits 36-43) of the LEVELING frames sent, each new value once.
    local sent
    sent=$(awk -v H=0123456789ABCDEF '{
      split($3, f, "#"); h = toupper(f[2])
      c = (index(H, substr(h, 9, 1)) - 1) + 16 * (index(H, substr(h, 12, 1)) - 1)
      if (NR == 1 || c != last) print c; last = c
    }' "$dir/out.log" | tail -n 2 | tr '\n' ' ')
    # leveld itself reads the saved state back (`leveld status`, daemon not running).
    local summary count
    summary=$({ "$bin" status --config "$dir/leveld.toml" 2>/dev/null || true; } | sed -n 's/^saved state: //p')
    case "$summary" in
      "none at"*) count=0 ;;
      *unusable*) count="unusable: $summary" ;;
      *windows*) count=$(printf '%s' "$summary" | sed -n 's/.*(\([0-9]*\) windows).*/\1/p') ;;
      *) count=0 ;;
    esac
    [ -n "$count" ] || count=0
    case "$count" in
      unusable*) unreadable=$((unreadable + 1)); echo "lane $l cycle $i: $count" >&2 ;;
      *)
        # What may be on disk: the last two counts sent, or, if nothing was sent, what
        # was there before.
        local allowed=" ${sent:-$saved } "
        if [[ "$allowed" != *" $count "* ]]; then
          backwards=$((backwards + 1))
          echo "lane $l cycle $i: $count windows saved, sent [${sent}], saved before $saved" >&2
        fi
        if [ "$count" != "$saved" ]; then saves=$((saves + 1)); fi
        saved=$count
        if [ "$count" -gt "$best" ]; then best=$count; fi
        ;;
    esac
    if [ "$(sha256sum < "$dir/calibration.json")" != "$cal_sum" ]; then
      echo "lane $l cycle $i: the calibration file changed" >&2
      unreadable=$((unreadable + 1))
    fi
    if [ $((i % 25)) -eq 0 ]; then
      echo "lane $l: $i cycles, $unreadable unreadable, $backwards not sent, $saves saves seen"
    fi
  done
  echo "$l $n $unreadable $backwards $best $saves" > "$dir/result"
}

start=$(date +%s)
per=$(( (cycles + lanes - 1) / lanes ))
for l in $(seq 1 "$lanes"); do lane "$l" "$per" & done
wait
secs=$(( $(date +%s) - start ))
total=0 bad=0 back=0
echo "| lane | cycles | unreadable | not a sent count | most windows | saves seen |"
echo "| --- | --- | --- | --- | --- | --- |"
for l in $(seq 1 "$lanes"); do
  read -r _ n u b w s < "$work/lane$l/result"
  echo "| $l | $n | $u | $b | $w | $s |"
  total=$((total + n)); bad=$((bad + u)); back=$((back + b))
done
echo "soak: $total kill -9 cycles in $secs s: $bad unreadable, $back saved counts the daemon had not sent"
[ "$bad" -eq 0 ] && [ "$back" -eq 0 ]
exit
}
