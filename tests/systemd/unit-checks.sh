#!/bin/bash
# The .deb under real systemd: run inside the VM booted with systemd as PID 1
# (LEVELD_VM_SYSTEMD=1 tools/vcan-vm.sh, see tools/test-all.sh), with a vcan named can0.
#
#   tests/systemd/unit-checks.sh PACKAGE.deb DRIVE.log
#
# DRIVE.log is a simulated drive on can0 (candump -L) that gives the daemon an
# estimate. Prints one `ok` or `not ok` line per check; exits with the number failed.
set -u
deb=$1 drive=$2
fails=0
ok() { echo "ok - $*"; }
bad() { echo "not ok - $*"; fails=$((fails + 1)); }
check() { local what=$1; shift; if "$@"; then ok "$what"; else bad "$what"; fi; }
prop() { systemctl show -p "$1" --value leveld; }
# Wait up to $1 s for the command to succeed.
wait_for() { local n=$(($1 * 5)); shift; while ! "$@"; do n=$((n - 1)); [ $n -le 0 ] && return 1; sleep 0.2; done; }
leveling() { candump -L -n "$1" -T "$2" can0,3E8:7FF 2>/dev/null | wc -l; }

echo "# systemd $(systemctl --version | head -n 1)"

# --- install --------------------------------------------------------------------------
# No man-db index rebuild on install: it takes minutes under emulation, and `man NAME`
# finds the pages without it.
rm -f /var/lib/man-db/auto-update
check "dpkg installs the package" dpkg -i "$deb"
systemctl daemon-reload
check "the unit is enabled by the package" test "$(systemctl is-enabled leveld 2>&1)" = enabled
check "config and DBC are conffiles" sh -c 'dpkg-query --showformat="\${Conffiles}" -W leveld | grep -q /etc/leveld/leveld.toml && dpkg-query --showformat="\${Conffiles}" -W leveld | grep -q /etc/leveld/leveld.dbc'
check "the installed config is valid" sh -c 'leveld check-config | tail -n 1 | grep -qx ok'
check "the packaged daemon has no simulator" sh -c '! leveld simulate --help >/dev/null 2>&1'
check "man renders the pages (leveld, leveld-status)" sh -c 'MANPAGER=cat MANWIDTH=80 man leveld 2>/dev/null | grep -q "leveld-status(1)" && MANPAGER=cat MANWIDTH=80 man leveld-status 2>/dev/null | grep -q -- "--format"'
check "bash -n accepts the bash completion" bash -n /usr/share/bash-completion/completions/leveld
check "the bash completion completes subcommands" bash -c 'source /usr/share/bash-completion/completions/leveld; COMP_WORDS=(leveld st); COMP_CWORD=1; COMP_LINE="leveld st"; COMP_POINT=9; _leveld leveld st leveld; printf "%s\n" "${COMPREPLY[@]}" | grep -qx status'
for f in /usr/share/zsh/vendor-completions/_leveld /usr/share/fish/vendor_completions.d/leveld.fish; do
  check "$f is in the package" test -s "$f"
done
command -v zsh >/dev/null && check "zsh -n accepts the zsh completion" zsh -n /usr/share/zsh/vendor-completions/_leveld
command -v fish >/dev/null && check "fish -n accepts the fish completion" fish -n /usr/share/fish/vendor_completions.d/leveld.fish

# --- start: active only after READY=1 -------------------------------------------------
check "systemctl start leveld succeeds" systemctl start leveld
# On failure, what the daemon said is the first thing to read.
systemctl is-active -q leveld || journalctl -u leveld -o cat --no-pager | tail -n 30 | sed 's/^/# /'
check "the unit is active" test "$(systemctl is-active leveld)" = active
# leveld logs "CAN open" just before READY=1; systemd logs "Started" when it arrives.
order=$(journalctl -b -o cat --no-pager | grep -n -e 'CAN open' -e 'Started leveld' | head -n 2 | cut -d: -f2-)
check "READY=1 comes after the sockets are open (CAN open, then Started)" sh -c "printf '%s\n' \"\$1\" | head -n 1 | grep -q 'CAN open' && printf '%s\n' \"\$1\" | sed -n 2p | grep -q 'Started leveld'" _ "$order"
check "LEVELING frames appear on the bus" test "$(leveling 5 3000)" -ge 5
check "the service runs as a dynamic user, not root" test "$(ps -o user= -p "$(prop MainPID)" | tr -d ' ')" != root

# --- a drive gives an estimate, saved in the state directory ----------------------------
canplayer -I "$drive"
sleep 6
st=$(leveld status --format json)
echo "# leveld status: $st"
est=$(printf '%s' "$st" | python3 -c 'import json,sys; r=json.load(sys.stdin)["report"]; print("%.9f" % r["road_to_body_deg"] if r and r["road_to_body_deg"] is not None else "none")')
check "leveld status reports the running daemon's estimate ($est deg)" sh -c "leveld status >/dev/null && [ '$est' != none ]"
check "leveld status (text) names the inputs and the last save" sh -c 'leveld status | grep -q "WHL_SPD11" && leveld status | grep -q "last save: [0-9]* s ago"'
check "systemctl status shows the daemon's status line" sh -c 'systemctl status leveld --no-pager | grep -q "Status: \".*road-to-body"'
check "the state is saved under /var/lib/leveld" sh -c 'grep -q averager /var/lib/leveld/state.json'

# --- hardening at run time --------------------------------------------------------------
pid=$(prop MainPID)
socks=$(ls -l /proc/"$pid"/fd | sed -n 's/.*socket:\[\([0-9]*\)\].*/\1/p')
foreign=0
for ino in $socks; do
  for t in tcp tcp6 udp udp6 raw raw6 packet netlink; do
    awk -v i="$ino" 'NR > 1 { for (k = 1; k <= NF; k++) if ($k == i) f = 1 } END { exit !f }' /proc/"$pid"/net/$t 2>/dev/null && foreign=$((foreign + 1))
  done
done
check "the daemon holds CAN sockets ($(echo $socks | wc -w)) and no inet, packet or netlink socket" test -n "$socks" -a "$foreign" = 0
# A probe with the unit's own sandbox: what may it write and open?
sed -e 's/^Type=.*/Type=oneshot/' -e '/^WatchdogSec=/d' -e '/^Restart/d' -e '/^RuntimeDirectory/d' \
    -e 's|^ExecStart=.*|ExecStart=/bin/bash /usr/local/lib/leveld-probe.sh\nTimeoutStartSec=60|' \
    /usr/lib/systemd/system/leveld.service > /etc/systemd/system/leveld-probe.service
mkdir -p /usr/local/lib
cat > /usr/local/lib/leveld-probe.sh <<'PROBE'
n=0
no() { if "$@" 2>/dev/null; then echo "probe: allowed: $*"; n=$((n + 1)); fi; }
yes() { if ! "$@"; then echo "probe: refused: $*"; n=$((n + 1)); fi; }
no sh -c 'echo x > /etc/leveld/probe'
no sh -c 'echo x > /usr/bin/probe'
no sh -c 'echo x > /var/lib/probe'
no sh -c 'echo x > /root/probe'
yes sh -c 'echo x > /var/lib/leveld/probe && rm /var/lib/leveld/probe'
# Each address family but CAN and Unix fails with EAFNOSUPPORT (97).
e=$(/usr/bin/python3 -c '
import socket
for name, fam, kind, proto in (("inet", socket.AF_INET, socket.SOCK_STREAM, 0), ("inet6", socket.AF_INET6, socket.SOCK_DGRAM, 0),
                               ("netlink", socket.AF_NETLINK, socket.SOCK_RAW, 0), ("packet", socket.AF_PACKET, socket.SOCK_RAW, 0),
                               ("can", socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW), ("unix", socket.AF_UNIX, socket.SOCK_DGRAM, 0)):
    try:
        socket.socket(fam, kind, proto).close()
        print(name, "open")
    except OSError as x:
        print(name, x.errno)
' 2>&1)
echo "$e" | sed 's/^/probe: socket /'
[ "$e" = "$(printf 'inet 97\ninet6 97\nnetlink 97\npacket 97\ncan open\nunix open')" ] || { echo "probe: unexpected socket families"; n=$((n + 1)); }
yes timeout 10 candump -n 1 can0
echo "probe: $n unexpected"
exit $n
PROBE
systemctl daemon-reload
check "the unit's sandbox writes only its state directory and opens only AF_CAN and AF_UNIX" systemctl start leveld-probe
journalctl -u leveld-probe -o cat --no-pager | grep '^probe:' | sed 's/^/# /'

# --- kill -9: restarted, the estimate resumes from the state file -------------------------
n0=$(prop NRestarts)
kill -9 "$pid"
check "after kill -9 systemd restarts the daemon" wait_for 20 sh -c "[ \"\$(systemctl show -p MainPID --value leveld)\" != 0 ] && [ \"\$(systemctl show -p MainPID --value leveld)\" != $pid ] && systemctl is-active -q leveld"
check "NRestarts counts the restart" test "$(prop NRestarts)" = $((n0 + 1))
sleep 2
est2=$(leveld status --format json | python3 -c 'import json,sys; r=json.load(sys.stdin)["report"]; print("%.9f" % r["road_to_body_deg"] if r and r["road_to_body_deg"] is not None else "none")')
check "the restarted daemon resumes the saved estimate ($est2 deg, was $est)" test "$est2" = "$est"

# --- watchdog: a daemon that stops petting is restarted ------------------------------------
pid=$(prop MainPID)
n0=$(prop NRestarts)
kill -STOP "$pid"
check "a stopped daemon is killed by the watchdog and restarted" wait_for 40 sh -c "[ \"\$(systemctl show -p MainPID --value leveld)\" != 0 ] && [ \"\$(systemctl show -p MainPID --value leveld)\" != $pid ] && systemctl is-active -q leveld"
check "the journal names the watchdog" sh -c 'journalctl -u leveld -o cat --no-pager | grep -qi "watchdog timeout"'
check "NRestarts counts it" test "$(prop NRestarts)" = $((n0 + 1))
check "LEVELING frames flow again" test "$(leveling 5 3000)" -ge 5

# --- stop: state saved, exit 0 ---------------------------------------------------------------
before=$(stat -c %Y /var/lib/leveld/state.json)
sleep 1.1
check "systemctl stop leveld succeeds" systemctl stop leveld
check "the daemon exited 0 (Result=success)" test "$(prop Result)/$(prop ExecMainStatus)" = success/0
check "the stop saved the state" sh -c "[ \$(stat -c %Y /var/lib/leveld/state.json) -gt $before ] && journalctl -u leveld -o cat --no-pager | grep -q 'state saved; exiting'"
out=$(leveld status); rc=$?
printf '%s\n' "$out" | sed 's/^/# /'
check "leveld status after the stop says not running (exit 3) and shows the saved estimate" sh -c "[ $rc = 3 ] && printf '%s\n' \"\$1\" | grep -q 'not running' && printf '%s\n' \"\$1\" | grep -q 'saved state: road-to-body'" _ "$out"

echo "# $fails failed"
exit "$fails"
