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

# Test binaries that only compute, with no clock of their own (Open3D's
# TSDF fusion, renders of the whole building, `star map` on a scanned
# map): they run beside everything else at the lowest priority, where the
# other tests leave the cores idle (50 Hz replays, the SITL flights in real
# time, the soak: about 1.4 of 2 cores busy in `cargo test`, 0.7 in pytest).
# The tests that replay at 50 Hz or search against a time budget stay in
# the foreground, at normal priority. Timings: docs/ci.md.
background=(synth_scanned map_cli render_building_cull)
foreground=(--lib)
for file in tests/*.rs; do
  name="$(basename "$file" .rs)"
  case " ${background[*]} " in
    *" $name "*) ;;
    *) foreground+=(--test "$name") ;;
  esac
done
background_log="$(mktemp)"
background_args=()
for name in "${background[@]}"; do background_args+=(--test "$name"); done
nice -n 19 cargo test --release "${background_args[@]}" >"$background_log" 2>&1 &
background_pid=$!
trap 'kill "$background_pid" 2>/dev/null || true; rm -f "$background_log"' EXIT

cargo test --release "${foreground[@]}"
cargo test --release --doc
"$STAR_VENV/bin/python" -m pytest -q hil_tests

if wait "$background_pid"; then
  background_status=0
else
  background_status=$?
fi
echo "test: the tests run beside the others at nice 19 (${background[*]}):"
cat "$background_log"
if [ "$background_status" -ne 0 ]; then
  echo "test: ${background[*]} failed (exit $background_status)" >&2
  exit 1
fi
