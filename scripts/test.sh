#!/usr/bin/env bash
# The README's test command: unit and integration tests (cargo test --release),
# then the full judge suite with every GPU case required to run. On a machine
# without a Vulkan adapter it installs Mesa's software driver (lavapipe) first
# (scripts/gpu_setup.sh). The last line printed is the judge's summary,
# `N passed, N failed, N skipped` (repeated after the run's HTML report is
# checked in headless Chromium: scripts/report_check.sh, which installs
# Debian's chromium when missing and writes the screenshot out/suite/report.png).
# Exit status: non-zero if anything failed.
# The workspace's second package, capi/ (the C ABI), is tested by the same
# cargo test: its C program and its Python example (numpy installed here when
# missing) against hpjudge render.
set -euo pipefail
cd "$(dirname "$0")/.."
hpjudge="${CARGO_TARGET_DIR:-target}/release/hpjudge"

echo "== build"
cargo build --release --bin hpjudge

echo "== GPU adapter"
# shellcheck source=scripts/gpu_setup.sh
source scripts/gpu_setup.sh
hp_gpu_setup "$hpjudge" || echo "no GPU adapter: every GPU case will fail (--require-gpu)"

echo "== Python with numpy (the C ABI's ctypes example, issue 20)"
if command -v python3 >/dev/null 2>&1 && ! python3 -c "import numpy" 2>/dev/null; then
    python3 -m pip install -q numpy >&2 || echo "numpy not installed: the Python example will be skipped"
fi

echo "== glmark2-data (the bunny mesh of TESTS/scenes/bunny.yaml, issue 14)"
if [ ! -f /usr/share/glmark2/models/bunny.obj ]; then
    sudo=""
    if [ "$(id -u)" != 0 ] && command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        sudo="sudo -n"
    fi
    { $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq &&
        $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq glmark2-data; } >&2 ||
        echo "glmark2-data not installed: the bunny cases skip (and fail with CI=true)"
fi

echo "== cargo test --release --workspace"
cargo test --release --workspace

echo "== hpjudge run TESTS/manifest.yaml --require-gpu"
mkdir -p out/suite
status=0
"$hpjudge" run TESTS/manifest.yaml --out out/suite --junit out/suite/junit.xml --require-gpu \
    | tee out/suite.log || status=1

echo "== hpjudge report out/suite (checked in headless Chromium)"
scripts/report_check.sh out/suite || status=1
tail -n 1 out/suite.log
exit "$status"
