#!/usr/bin/env bash
# Every test: the Rust suite (`cargo test --release`), a single-node Slurm running the README's
# job array (tools/slurm_test.sh), then the Python package and the HTML report in a browser (pytest, in a fresh virtual environment under target/, with the package
# installed by `pip install ./python`). Installs what they need on a fresh machine: pytest,
# numpy, pandas, gymnasium, playwright, mcap, mcap-ros2-support and rosbags (independent readers
# and writers of MCAP and rosbag2) from PyPI, and Debian's chromium (plus python3-venv
# if venv is missing) with apt-get, as root or with sudo.
# AIFT_SCREENSHOTS=DIR keeps the report pages' screenshots in DIR.
set -euo pipefail
if [ -n "${AIFT_SCREENSHOTS:-}" ]; then
  AIFT_SCREENSHOTS=$(realpath -m "$AIFT_SCREENSHOTS")
  export AIFT_SCREENSHOTS
fi
cd "$(dirname "$0")/.."
root=$(pwd)

apt_install() {
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  echo "== apt-get install $*" >&2
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get install -y "$@" >/dev/null 2>&1 \
    || { $sudo apt-get update >/dev/null && $sudo apt-get install -y "$@" >/dev/null; }
}

cargo test --release
# The tests built target/release/aift; build it only if they did not.
[ -x target/release/aift ] || cargo build --release --bin aift

# A real scheduler: the README's Slurm job array, scaled down, merged and compared byte for byte
# with the unsharded campaign (installs Debian's slurm-wlm and munge if missing).
echo "== tools/slurm_test.sh" >&2
tools/slurm_test.sh

[ -x /usr/bin/chromium ] || apt_install chromium
python3 -m venv --help >/dev/null 2>&1 || apt_install python3-venv

venv="$root/target/pytest-venv"
echo "== fresh virtual environment $venv; pip install ./python" >&2
rm -rf "$venv"
python3 -m venv "$venv"
"$venv/bin/pip" install -q pytest numpy pandas gymnasium playwright mcap mcap-ros2-support rosbags
"$venv/bin/pip" install -q ./python
# From outside python/, so that `import aift` is the installed package, not the source folder.
cd "$venv"
echo "== pytest $root/python/tests" >&2
AIFT_BIN="$root/target/release/aift" "$venv/bin/python" -m pytest -q "$root/python/tests"
