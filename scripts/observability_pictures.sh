#!/usr/bin/env bash
# Makes the pictures of docs/observability.md and the README's "Seeing what
# the tracker sees" from a release build and the Python venv (OpenCV, to
# scale the view strip down and to write the dark frames):
#
#   docs/demo_trajectory.png     `star eval --plot` of `star localize` on
#                                `star synth --preset realistic` (seed 1,
#                                500 frames), events from the flight log;
#   docs/keyframe_residual.png   a view strip of that run's flight log
#                                (`--record-views`): camera frame, keyframe
#                                render, frame warped into the keyframe,
#                                photometric residual; scaled to half size;
#   docs/blackout_trajectory.png the same sequence with frames 200-229
#                                replaced by a dark frame (a lens cap),
#                                localized with a relocalization database:
#                                the loss and the relocalization marked.
#
# Usage: scripts/observability_pictures.sh [WORK_DIR] (default out/pictures).
# About three minutes on the development machine, most of it the
# relocalization database.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
star="$root/target/release/star"
python="${STAR_VENV:-$root/.venv}/bin/python"
out="${1:-$root/out/pictures}"
docs="$root/docs"
[[ -x "$star" ]] || { echo "pictures: build first (cargo build --release)" >&2; exit 1; }
[[ -x "$python" ]] || { echo "pictures: no venv at $python (scripts/setup.sh)" >&2; exit 1; }
if [[ -z "${XDG_RUNTIME_DIR:-}" ]]; then
    export XDG_RUNTIME_DIR="/tmp/xdg-runtime-$(id -u)"
    mkdir -p -m 700 "$XDG_RUNTIME_DIR"
fi
mkdir -p "$out"
data="$out/realistic"
if [[ ! -f "$data/rgb.txt" ]]; then
    "$star" --log warn synth --preset realistic "$data" --frames 500 --seed 1 --no-depth
fi

echo "pictures: localize with the flight log"
rm -rf "$out/record"
"$star" --log warn localize "$data" -o "$out/est.txt" \
    --record "$out/record" --record-every 50 --record-views
"$star" eval "$data/groundtruth.txt" "$out/est.txt" --frames "$out/record" \
    --plot "$docs/demo_trajectory.png" --plot-size 1200x675
"$python" - "$out/record/views/000250.png" "$docs/keyframe_residual.png" <<'PY'
import sys, cv2
strip = cv2.imread(sys.argv[1], cv2.IMREAD_GRAYSCALE)
h, w = strip.shape
half = cv2.resize(strip, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
cv2.imwrite(sys.argv[2], half, [cv2.IMWRITE_PNG_COMPRESSION, 9])
PY

echo "pictures: a blackout of 30 frames, with a relocalization database"
dark="$out/blackout"
rm -rf "$dark"
mkdir -p "$dark/rgb"
for f in camera.toml groundtruth.txt rgb.txt map; do ln -s "$data/$f" "$dark/$f"; done
"$python" - "$data" "$dark" <<'PY'
import os, sys, cv2, numpy as np
src, dst = sys.argv[1], sys.argv[2]
frames = [l.split()[1] for l in open(os.path.join(src, "rgb.txt"))
          if l.strip() and not l.startswith("#")]
for i, rel in enumerate(frames):
    if 200 <= i < 230:
        image = cv2.imread(os.path.join(src, rel), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(os.path.join(dst, rel), np.full_like(image, 20))
    else:
        os.symlink(os.path.join(src, rel), os.path.join(dst, rel))
PY
if [[ ! -f "$out/realistic.reloc" ]]; then
    "$star" --log warn reloc build --map "$data/map/map.obj" --camera "$data/camera.toml" \
        -o "$out/realistic.reloc"
fi
rm -rf "$out/record_blackout"
"$star" --log warn localize "$dark" -o "$out/est_blackout.txt" --reloc "$out/realistic.reloc" \
    --record "$out/record_blackout" --record-every 0
"$star" eval "$data/groundtruth.txt" "$out/est_blackout.txt" --frames "$out/record_blackout" \
    --plot "$docs/blackout_trajectory.png" --plot-size 1200x675
ls -l "$docs/demo_trajectory.png" "$docs/keyframe_residual.png" "$docs/blackout_trajectory.png"
