#!/usr/bin/env bash
# Tracker accuracy benchmark: synthesizes each preset (500 frames = 10 s at
# 50 Hz, fixed seed), localizes it against its map through the CPU rasterizer
# and through wgpu on the software adapter (lavapipe; `renderer = "auto"`
# takes the CPU rasterizer where there is no hardware GPU; on a machine with
# one, STAR_BENCH_RENDERERS="cpu gpu"), with frames
# delivered at the recorded 50 Hz as a camera would (`--realtime`; set
# STAR_BENCH_UNPACED=1 to feed them as fast as the tracker takes them, which
# starves the render thread of time on two cores), and prints ATE
# (no alignment), lost frames and timing; then compares the two illumination
# models on `realistic`. Prints figures; never fails on them.
# Usage: scripts/bench_accuracy.sh [FRAMES] [SEED]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
star="$root/target/release/star"
frames="${1:-500}"
seed="${2:-1}"
pace=(--realtime)
if [[ -n "${STAR_BENCH_UNPACED:-}" ]]; then pace=(); fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
export RUST_LOG=error

summary() { grep -E "frames|tracking time|ATE|quality" | sed 's/^/    /'; }

for preset in ideal realistic aggressive; do
  "$star" synth --preset "$preset" --seed "$seed" --frames "$frames" --no-depth "$work/$preset" | tail -n 1
  for renderer in ${STAR_BENCH_RENDERERS:-cpu software}; do
    printf '[render]\nrenderer = "%s"\n' "$renderer" > "$work/render.toml"
    echo "  $preset, renderer $renderer:"
    "$star" localize "$work/$preset" "${pace[@]}" --config "$work/render.toml" -o "$work/$preset/est_$renderer.txt" 2>/dev/null | summary
  done
done

echo "illumination model on realistic (renderer auto):"
for model in affine median; do
  printf '[tracker]\nillumination = "%s"\n' "$model" > "$work/illum.toml"
  echo "  $model:"
  "$star" localize "$work/realistic" "${pace[@]}" --config "$work/illum.toml" -o "$work/realistic/est_$model.txt" 2>/dev/null | summary
done
