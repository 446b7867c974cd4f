#!/usr/bin/env bash
# Regenerates the committed campaign folders with this build, with the commands results/README.md
# names (detector calibration on the fly, cache off): the development campaign (results/campaign,
# 10 seeds, every method; about 1 h on a 2-core machine), the evaluation campaign
# (results/campaign-eval, about 1 h 40 min), the actuator/timing/disturbance campaign
# (results/actuators, 3-7 min) and the healthy reaching benchmark (results/reaching, 7 min).
# A campaign stages its output and replaces a folder only when it is complete; a killed one
# resumes when the same command runs again (docs/campaigns.md, "Resuming").
# Usage: tools/regen-campaigns.sh [dev] [eval] [actuators] [reaching]   (none: all four)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
export AIFT_CACHE_DIR=off
aift=./target/release/aift
all=(dev eval actuators reaching)
which=("$@")
[ ${#which[@]} -gt 0 ] || which=("${all[@]}")
methods=no-ft,pl-always,hybrid,ekf-gate,vb-akf,imm,oracle
for w in "${which[@]}"; do
    echo "== $w ($(date -u +%H:%M:%S))" >&2
    case "$w" in
        dev) $aift campaign --seeds 10 --methods "$methods" --out results/campaign --force ;;
        eval) $aift campaign assets/campaigns/eval.toml --methods "$methods" \
                  --out results/campaign-eval --force ;;
        actuators) $aift campaign assets/campaigns/actuators.toml --out results/actuators --force ;;
        reaching) $aift campaign assets/campaigns/reaching.toml --out results/reaching --force ;;
        *) echo "regen-campaigns: unknown campaign '$w' (dev, eval, actuators, reaching)" >&2; exit 2 ;;
    esac
done
