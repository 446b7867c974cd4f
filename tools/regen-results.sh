#!/usr/bin/env bash
# Regenerates the committed Monte Carlo tables: every bundled scenario at 20 seeds, every
# method, detector calibrated on the fly (50 healthy runs, cache disabled so the timings in the
# logs are honest); with no names, also the authors' reaching protocol (results/authors_reaching/).
# Usage: tools/regen-results.sh [SCENARIO_NAME ...]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
export AIFT_CACHE_DIR=off
names=("$@")
if [ ${#names[@]} -eq 0 ]; then
    for f in assets/scenarios/*.toml; do
        # The authors' compatibility scenario has no camera (nominal precision 0): it runs no-ft
        # only, in its campaign below.
        [ "$(basename "$f")" = authors_matlab.toml ] || names+=("$(basename "$f" .toml)")
    done
    ./target/release/aift campaign assets/campaigns/authors_reaching.toml \
        --out results/authors_reaching --force > results/authors_reaching.log 2>&1
fi
for n in "${names[@]}"; do
    echo "== $n" >&2
    # Tables written before output folders were marked: --force replaces marked folders only.
    if [ -d "results/$n" ] && [ ! -e "results/$n/.aift-output" ]; then rm -rf "results/$n"; fi
    ./target/release/aift table "assets/scenarios/$n.toml" --seeds 20 --out "results/$n" --force \
        > "results/$n.log" 2>&1
done
