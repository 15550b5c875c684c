#!/usr/bin/env bash
# The demo: synthesize the default scene and render one frame of it.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
star="$root/target/release/star"
out="${STAR_DEMO_OUT:-$root/out/demo}"
mkdir -p "$out"
"$star" check-config "$root/config/star.toml" > /dev/null
echo "demo: configuration ok"
