#!/usr/bin/env bash
# Every test of leveld: unit, simulation, replay and (where SocketCAN can be had) vcan.
# Installs what it needs on a fresh Debian machine; safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
command -v python3 >/dev/null || need_apt+=(python3 python3-pip)
command -v systemd-analyze >/dev/null || need_apt+=(systemd)
if [ ${#need_apt[@]} -gt 0 ] && [ "$(id -u)" = 0 ]; then
  apt-get update -qq && apt-get install -y -qq "${need_apt[@]}"
fi
# cantools is the independent decoder the DBC and codec tests compare against.
if ! python3 -c 'import cantools' 2>/dev/null; then
  python3 -m pip install -q cantools 2>/dev/null || python3 -m pip install -q --break-system-packages cantools
fi

if command -v cargo-nextest >/dev/null 2>&1; then
  cargo nextest run --workspace --no-fail-fast
else
  cargo test --workspace --no-fail-fast
fi
