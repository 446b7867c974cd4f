#!/usr/bin/env bash
# Every test: the Rust suite (`cargo test --release`), then the Python package and the HTML
# report in a browser (pytest, in a fresh virtual environment under target/, with the package
# installed by `pip install ./python`). Installs what they need on a fresh machine: pytest,
# numpy, pandas, gymnasium and playwright from PyPI, and Debian's chromium when
# /usr/bin/chromium is missing (apt-get; root or sudo).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

cargo test --release
cargo build --release --bin aift

if [ ! -x "${AIFT_CHROMIUM:-/usr/bin/chromium}" ]; then
  echo "== installing Debian's chromium (the report's browser test)" >&2
  sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get install -y chromium >/dev/null 2>&1 \
    || { $sudo apt-get update >/dev/null && $sudo apt-get install -y chromium >/dev/null; }
fi

venv="$root/target/pytest-venv"
echo "== fresh virtual environment $venv; pip install ./python" >&2
rm -rf "$venv"
python3 -m venv "$venv"
"$venv/bin/pip" install -q pytest numpy pandas gymnasium playwright
"$venv/bin/pip" install -q ./python
# Screenshots of the report pages go to $AIFT_SCREENSHOTS when set (made absolute here).
if [ -n "${AIFT_SCREENSHOTS:-}" ]; then
  AIFT_SCREENSHOTS=$(realpath -m "$AIFT_SCREENSHOTS")
  export AIFT_SCREENSHOTS
fi
# From outside python/, so that `import aift` is the installed package, not the source folder.
cd "$venv"
AIFT_BIN="$root/target/release/aift" "$venv/bin/python" -m pytest -q "$root/python/tests"
