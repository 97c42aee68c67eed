#!/usr/bin/env bash
# Build the ECU package: target/debian/leveld_<version>-1_<arch>.deb.
#
# The daemon is built without the simulator and benchmark (profile `deb`). Its man
# page and shell completions are generated from the CLI definition, and the config is
# the shipped one with the DBC beside it in /etc/leveld.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo-deb >/dev/null || cargo install --locked cargo-deb
cargo build --profile deb --no-default-features
bin=target/deb/leveld
mkdir -p target/package
rm -rf target/package/man && mkdir -p target/package/man
"$bin" man target/package/man
gzip -9n target/package/man/*.1
"$bin" completions bash > target/package/leveld.bash
"$bin" completions zsh > target/package/_leveld
"$bin" completions fish > target/package/leveld.fish
sed 's|^dbc = .*|dbc = "leveld.dbc"|' config/leveld.toml > target/package/leveld.toml
grep -q '^dbc = "leveld.dbc"$' target/package/leveld.toml
cargo deb --no-build --profile deb -q
ls target/debian/leveld_*.deb
