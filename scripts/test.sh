#!/usr/bin/env bash
# The README's test command: unit and integration tests (cargo test --release),
# then the full judge suite. The last line printed is the judge's summary,
# `N passed, N failed, N skipped`. Exit status: non-zero if anything failed.
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== cargo test --release"
cargo test --release

echo "== hpjudge run TESTS/manifest.yaml"
cargo build --release --bin hpjudge
mkdir -p out/suite
./target/release/hpjudge run TESTS/manifest.yaml --out out/suite --junit out/suite/junit.xml
