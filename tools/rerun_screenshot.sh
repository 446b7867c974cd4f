#!/usr/bin/env bash
# Opens a run's run.mcap in Rerun's native viewer on a virtual display (software Vulkan) and
# saves a screenshot; also runs Rerun's own MCAP checker on it. Opt-in (not in CI: it installs
# Debian's xvfb and mesa-vulkan-drivers and PyPI's rerun-sdk, about 200 MB).
#
#   tools/rerun_screenshot.sh [OUT.png]     (default docs/images/rerun_run_mcap.png)
#
# Produced docs/images/rerun_run_mcap.png on 2026-12-04 with rerun-sdk 0.41.0 (then scaled
# to 1600 x 1000 with Pillow).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-docs/images/rerun_run_mcap.png}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
if ! command -v xvfb-run >/dev/null; then
    apt-get install -y -q xvfb mesa-vulkan-drivers >/dev/null
fi
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q rerun-sdk==0.41.0 pillow
cargo build --release -q
./target/release/aift run assets/scenarios/paper_encoder_freeze.toml --method hybrid --mcap \
    --out "$work/run" --json >/dev/null
"$work/venv/bin/rerun" mcap check --full "$work/run/run.mcap"
xvfb-run -s "-screen 0 1600x1000x24" "$work/venv/bin/rerun" "$work/run/run.mcap" \
    --window-size 1600x1000 --screenshot-to "$work/shot.png"
"$work/venv/bin/python" - "$work/shot.png" "$out" <<'PY'
import sys
from PIL import Image
Image.open(sys.argv[1]).convert("RGB").resize((1600, 1000), Image.LANCZOS).save(sys.argv[2], optimize=True)
PY
echo "wrote $out"
