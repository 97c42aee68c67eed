#!/usr/bin/env bash
# Every test of leveld: unit, simulation, replay, and the vcan suite on a real
# SocketCAN stack (this machine's kernel, or a small VM; see tools/vcan-vm.sh).
# Installs what it needs on a fresh Debian machine; safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }
need_apt=()
command -v python3 >/dev/null || need_apt+=(python3 python3-pip)
command -v systemd-analyze >/dev/null || need_apt+=(systemd)
command -v man >/dev/null || need_apt+=(man-db)
[ -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ] || need_apt+=(fonts-dejavu-core)
if [ ${#need_apt[@]} -gt 0 ]; then
  as_root apt-get update -qq
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi
# cantools is the independent decoder the DBC, codec and output tests compare against.
if ! python3 -c 'import cantools' 2>/dev/null; then
  python3 -m pip install -q cantools 2>/dev/null || python3 -m pip install -q --break-system-packages cantools
fi

echo "== rustfmt and clippy"
if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
  rustup component add rustfmt clippy
fi
cargo fmt --check
cargo clippy --all-targets -- -D warnings

echo "== unit, simulation, replay and daemon tests"
if command -v cargo-nextest >/dev/null 2>&1; then
  cargo nextest run --workspace --no-fail-fast
else
  cargo test --workspace --no-fail-fast
fi

echo "== vcan suite: leveld run against canplayer and candump on a virtual CAN bus"
bin=$(cargo test --test vcan --no-run --message-format=json 2>/dev/null | python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("target", {}).get("name") == "vcan" and m.get("executable"):
        print(m["executable"])
')
[ -n "$bin" ] || { echo "cannot build the vcan test binary" >&2; exit 1; }
tools/vcan-vm.sh "$bin" --ignored --test-threads=1

echo "== package: the .deb built and checked under real systemd (VM with systemd as PID 1)"
tools/package.sh
deb=$(ls -t target/debian/leveld_*.deb | head -n 1)
# A 45 s simulated drive on can0 that gives the daemon an estimate to save and resume.
cargo run -q -- simulate drive --preset short --interface can0 --output target/package/vm-drive-full.log
awk '{ t = substr($1, 2, length($1) - 2) + 0; if (t < 1045) print }' target/package/vm-drive-full.log > target/package/vm-drive.log
LEVELD_VM_SYSTEMD=1 tools/vcan-vm.sh tests/systemd/unit-checks.sh "$deb" target/package/vm-drive.log
