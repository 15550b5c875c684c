#!/usr/bin/env bash
# The demo: the full pipeline on the embedded default scene.
#  1. synthesize the `realistic` preset (500 frames, 10 s at 50 Hz, ground truth);
#  2. `star run`: replay camera -> iceoryx2 -> tracker -> MAVLink (udpout to a
#     local port, where a pymavlink stand-in for the autopilot counts what
#     arrives, when the Python venv exists) and the iceoryx2 pose service;
#  3. ATE of the tracked trajectory against ground truth (`star eval`), with
#     the flight log's counts and the plot of the trajectory and its errors
#     ($out/trajectory.png; the flight log, `--record`, is in $out/record:
#     trajectory, per-frame CSV, every 25th frame and its view strip).
#
# `scripts/demo.sh --sitl` flies instead: ArduCopter SITL (../shared/sitl,
# or $STAR_SITL_DIR) with GPS off and EKF3 on star's vision only, the
# vehicle's camera rendered at SITL's true pose (`star camera --source
# sim:`), `star track` sending VISION_POSITION_ESTIMATE; the vehicle takes
# off to 1 m, flies a 2 m square at 0.5 m/s and lands (hil_tests/flight.py).
# Prints EKF and star against the truth, the delay and CPU use, and writes
# the top-down plot of the flown square to $out/sitl_square.png.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
sitl=""
for arg in "$@"; do
    case "$arg" in
        --sitl) sitl=1 ;;
        *) echo "usage: $0 [--sitl]" >&2; exit 2 ;;
    esac
done
# Set-up and build are idempotent: a fresh machine with only Rust gets its
# system packages and venv here (scripts/setup.sh), then a release build.
if [[ -z "${STAR_DEMO_NO_SETUP:-}" ]]; then
    export STAR_VENV="${STAR_VENV:-$root/.venv}"
    "$root/scripts/setup.sh"
    (cd "$root" && cargo build --release)
fi
star="$root/target/release/star"
out="${STAR_DEMO_OUT:-$root/out/demo}"
frames="${STAR_DEMO_FRAMES:-500}"
port="${STAR_DEMO_PORT:-14591}"
python="${STAR_VENV:-$root/.venv}/bin/python"
mkdir -p "$out"
# Mesa's software Vulkan complains on stderr when this is unset (containers).
if [[ -z "${XDG_RUNTIME_DIR:-}" ]]; then
    export XDG_RUNTIME_DIR="/tmp/xdg-runtime-$(id -u)"
    mkdir -p -m 700 "$XDG_RUNTIME_DIR"
fi
# The shipped config names /var/lib/star paths: check its values only.
"$star" check-config --values-only "$root/config/star.toml" > /dev/null
echo "demo: configuration ok"

if [[ -n "$sitl" ]]; then
    sitl_bin="${STAR_SITL_DIR:-$root/../shared/sitl}/arducopter"
    if [[ ! -x "$sitl_bin" ]]; then
        echo "demo: --sitl needs ArduPilot SITL at $sitl_bin (set STAR_SITL_DIR)" >&2
        exit 1
    fi
    if [[ ! -x "$python" ]]; then
        echo "demo: --sitl needs the Python venv at $python (run scripts/setup.sh)" >&2
        exit 1
    fi
    echo "demo: closed-loop flight on vision in ArduCopter SITL (about a minute)"
    rm -rf "$out/sitl/flight"
    STAR_BIN="$star" "$python" "$root/hil_tests/flight.py" "$out/sitl" --plot "$out/sitl_square.png"
    exit 0
fi

data="$out/dataset"
if [[ ! -f "$data/rgb.txt" ]] || [[ "$(grep -vc '^#' "$data/rgb.txt")" != "$frames" ]]; then
    echo "demo: synthesizing $frames frames of the realistic preset into $data"
    "$star" --log warn synth --preset realistic "$data" --frames "$frames" --seed 1
fi

# A private iceoryx2 prefix, so the demo never meets another pipeline.
prefix="demo$$_"
sed "s/prefix = \"iox2_\"/prefix = \"$prefix\"/" "$root/config/iceoryx2.toml" > "$out/iceoryx2.toml"
cleanup() {
    [[ -n "${rx_pid:-}" ]] && kill "$rx_pid" 2>/dev/null || true
    rm -f /dev/shm/"$prefix"* /tmp/iceoryx2/*/"$prefix"* 2>/dev/null || true
}
trap cleanup EXIT
cat > "$out/star.toml" <<TOML
[map]
mesh = "$data/map/map.obj"
[mavlink]
connection = "udpout:127.0.0.1:$port"
[ipc]
iceoryx2_config = "$out/iceoryx2.toml"
TOML

rx_out="$out/mavlink_rx.jsonl"
rm -f "$rx_out"
if [[ -x "$python" ]]; then
    "$python" "$root/hil_tests/mavlink_receiver.py" --listen "udpin:127.0.0.1:$port" \
        --duration 600 --out "$rx_out" > "$out/receiver.log" 2>&1 &
    rx_pid=$!
    for _ in $(seq 50); do grep -q ready "$out/receiver.log" 2>/dev/null && break; sleep 0.1; done
else
    echo "demo: no Python venv at $python; MAVLink is sent but not decoded (run scripts/setup.sh)"
fi

init="$(awk '!/^#/ { $1 = ""; sub(/^ /, ""); print; exit }' "$data/groundtruth.txt")"
echo "demo: star run (replay camera + tracker through iceoryx2, MAVLink to udp:$port)"
rm -rf "$out/record"
"$star" --log warn run --config "$out/star.toml" --source "replay:$data" \
    --init-pose "$init" --trajectory "$out/estimate.txt" \
    --record "$out/record" --record-every 25 --record-views | tee "$out/run.txt"

if [[ -n "${rx_pid:-}" ]]; then
    sleep 0.3
    kill -TERM "$rx_pid" 2>/dev/null || true
    wait "$rx_pid" 2>/dev/null || true
    rx_pid=""
    "$python" - "$rx_out" <<'PY'
import collections, json, sys
counts = collections.Counter()
for line in open(sys.argv[1]):
    r = json.loads(line)
    if r.get("kind") == "rx":
        counts[r["type"]] += 1
print("demo: MAVLink received by the autopilot stand-in (pymavlink, CRC checked): "
      + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
PY
fi
echo "demo: accuracy against ground truth"
rm -f "$out/trajectory.png"
"$star" eval "$data/groundtruth.txt" "$out/estimate.txt" \
    --frames "$out/record" --plot "$out/trajectory.png"
