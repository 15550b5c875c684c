#!/usr/bin/env bash
# The README's test command: installs what is missing (scripts/setup.sh),
# builds once in release, runs every Rust test, then the hardware-in-the-loop
# pytest harness in hil_tests/ against that same release build.
# Usage: scripts/test.sh
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
export STAR_VENV="${STAR_VENV:-$root/.venv}"
scripts/setup.sh
# The binary and the test targets; the benches are compiled (checked) by CI's
# clippy --all-targets and built by `cargo bench` (39 CPU-s here saved).
cargo build --release --bins --tests
cargo test --release
"$STAR_VENV/bin/python" -m pytest -q hil_tests
