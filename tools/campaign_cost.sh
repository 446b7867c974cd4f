#!/usr/bin/env bash
# Where the default campaign's time goes: one 15 s healthy run per bundled arm and method on the
# campaign's settings (articulated engine), its ticks/s from summary.json, times the campaign's
# runs per arm and method (39 cells x SEEDS seeds x 15 000 ticks). Prints CPU-seconds and shares
# per arm and per method. Usage: tools/campaign_cost.sh [SEEDS] (default 10). Needs a built
# target/release/aift and python3.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=${1:-10}
B=./target/release/aift
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
methods=(no-ft pl-always hybrid ekf-gate vb-akf imm oracle)
for arm in paper_healthy undamped2_healthy planar3_healthy spatial3_healthy spatial3low_healthy panda_healthy; do
  S=assets/scenarios/$arm.toml
  $B train-gp "$S" --out "$tmp/gp-$arm.json" >/dev/null
  for m in "${methods[@]}"; do
    $B run "$S" --method "$m" --seed 1 --set 'plant.engine="articulated"' --set duration=15.0 \
      --set "gp.model=\"$tmp/gp-$arm.json\"" --out "$tmp/run" --force >/dev/null
    python3 -c "import json,sys;print(sys.argv[1], sys.argv[2], json.load(open(sys.argv[3]))['ticks_per_second'])" \
      "$arm" "$m" "$tmp/run/summary.json" >> "$tmp/tps.txt"
  done
done
python3 - "$tmp/tps.txt" "$seeds" <<'PY'
import sys, collections
ticks = 39 * int(sys.argv[2]) * 15000
arm, method = collections.Counter(), collections.Counter()
for line in open(sys.argv[1]):
    a, m, tps = line.split()
    cost = ticks / float(tps)
    arm[a] += cost; method[m] += cost
total = sum(arm.values())
print(f"estimated CPU-seconds: {total:.0f}")
for name, c in list(arm.items()) + list(method.items()):
    print(f"{name}: {c:.0f} s ({100 * c / total:.0f} %)")
PY
