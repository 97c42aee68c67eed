#!/usr/bin/env bash
# Regenerate docs/accuracy.md from docs/accuracy.tmpl.md with the figures of the code
# in this tree (about 7 minutes on 2 idle cores).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q
bin=target/release/leveld
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

run() { echo "+ leveld $*" >&2; "$bin" "$@"; }
run simulate paper-grid --format summary > "$tmp/grid"
run bench accuracy --plots docs > "$tmp/base1"
run bench accuracy --seeds 8 > "$tmp/base8"
run bench accuracy --scenarios scenarios/realistic/*.toml --seeds 8 > "$tmp/real8"
run bench accuracy --ablation > "$tmp/abl"
run bench accuracy --ablation --scenarios scenarios/realistic/*.toml --seeds 4 > "$tmp/ablreal"

python3 - "$tmp" <<'PY'
import sys, pathlib
tmp = pathlib.Path(sys.argv[1])

def tables(name):
    """Markdown tables of a command's output, in order."""
    out, cur = [], []
    for line in (tmp / name).read_text().splitlines():
        if line.startswith("|"):
            cur.append(line)
        elif cur:
            out.append("\n".join(cur)); cur = []
    if cur:
        out.append("\n".join(cur))
    return out

real = tables("real8")
abl = tables("abl")
ablreal = tables("ablreal")
text = pathlib.Path("docs/accuracy.tmpl.md").read_text()
fill = {
    "{{GRID}}": "\n\n".join(tables("grid")),
    "{{BASE1}}": tables("base1")[0],
    "{{BASE8}}": tables("base8")[0],
    "{{REAL8}}": real[0],
    "{{REAL8STOPS}}": "\n\n".join(real[1:]),
    "{{ABLATION}}": "## 4. What each part is worth\n\n"
        "`leveld bench accuracy --ablation` switches one part off at a time "
        "(`paper-like`: all of them off, with eq. 17). On the drive suite, one seed:\n\n"
        + abl[0]
        + "\n\nOn the realistic family, four seeds (`--ablation --scenarios "
        "scenarios/realistic/*.toml --seeds 4`):\n\n" + ablreal[0],
}
for k, v in fill.items():
    text = text.replace(k, v)
pathlib.Path("docs/accuracy.md").write_text(text)
PY
echo "docs/accuracy.md written" >&2
