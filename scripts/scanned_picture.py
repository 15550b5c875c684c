#!/usr/bin/env python3
"""The README picture of the scanned preset: the map rendered at a frame's
true pose beside the camera frame itself.

    scripts/scanned_picture.py STAR DATASET FRAME OUT.png

STAR is the `star` binary, DATASET a folder written by
`star synth --preset scanned`, FRAME the frame index. The map is rendered by
`star render --config DATASET/star.toml` (so through the declared
`[map.world_from_mesh]`, registration error included) with the dataset's
pinhole intrinsics; the camera frame is undistorted with the dataset's lens
model (OpenCV) so both share one pinhole geometry. Black in the map render is
where the map has no surface. Both are scaled to 75 % and labelled.
"""

import subprocess
import sys
import tempfile
import tomllib

import cv2
import numpy as np
from PIL import Image, ImageDraw


def entries(path):
    with open(path, encoding="utf-8") as f:
        return [line.split() for line in f if line.strip() and not line.startswith("#")]


def main():
    if len(sys.argv) != 5:
        print(__doc__, file=sys.stderr)
        return 2
    star, root, index, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    with open(f"{root}/camera.toml", "rb") as f:
        cam = tomllib.load(f)
    stamp, rgb = entries(f"{root}/rgb.txt")[index]
    gt = {round(float(e[0]), 6): e[1:] for e in entries(f"{root}/groundtruth.txt")}
    pose = " ".join(gt[round(float(stamp), 6)])

    with tempfile.TemporaryDirectory() as tmp:
        rendered = f"{tmp}/map.png"
        subprocess.run(
            [star, "render", "--config", f"{root}/star.toml", f"--pose={pose}", "-o", rendered]
            + [f"--{k}={cam[k]}" for k in ("width", "height", "fx", "fy", "cx", "cy")],
            check=True,
            stdout=subprocess.DEVNULL,
            env={"RUST_LOG": "warn", "PATH": "/usr/bin:/bin"},
        )
        map_view = np.array(Image.open(rendered).convert("L"))

    frame = np.array(Image.open(f"{root}/{rgb}").convert("L"))
    k = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]], dtype=np.float64)
    d = cam.get("distortion", {})
    dist = np.array([d.get(n, 0.0) for n in ("k1", "k2", "p1", "p2", "k3")], dtype=np.float64)
    frame = cv2.undistort(frame, k, dist)

    scale = 0.75
    size = (int(cam["width"] * scale), int(cam["height"] * scale))
    panels = []
    for image, label in (
        (map_view, "scanned map (TSDF fusion, scan light baked in), rendered at the true pose"),
        (frame, f"camera frame {index} (moving light, auto-exposure, noise; undistorted)"),
    ):
        panel = Image.fromarray(image).resize(size, Image.Resampling.LANCZOS)
        draw = ImageDraw.Draw(panel)
        draw.rectangle([0, 0, size[0], 14], fill=0)
        draw.text((4, 2), label, fill=255)
        panels.append(panel)
    picture = Image.new("L", (2 * size[0] + 6, size[1]), 255)
    picture.paste(panels[0], (0, 0))
    picture.paste(panels[1], (size[0] + 6, 0))
    picture.save(out, optimize=True)
    print(f"wrote {out} ({picture.size[0]}x{picture.size[1]}) from {rgb} at pose {pose}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
