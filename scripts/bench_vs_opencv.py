#!/usr/bin/env python3
"""Side-by-side tracker benchmark: OpenCV 5's RGB odometry and the STAR
tracker on identical keyframe/frame pairs.

Usage: scripts/bench_vs_opencv.py PAIRS_DIR [--star target/release/star]

PAIRS_DIR is written by `star bench pairs PAIRS_DIR`: for pair i, the
rendered keyframe `kf_i.png` with its metric depth `kf_depth_i.png` (mm),
the camera frame `frame_i.png`, and the ground-truth keyframe_from_frame in
`pairs.txt`. OpenCV gets the keyframe gray + depth as the source frame and
the camera frame as the destination, one thread, from the identity, as STAR
does. OpenCV's frame preparation fails without a depth on the destination
too, so it gets the keyframe's depth there as well: information STAR does
not have (with an empty destination depth it finds no transform at all). Prints time and error
for each, then runs `star bench track PAIRS_DIR` for the STAR figures.
"""
import argparse
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np


def quat_to_rot(qx, qy, qz, qw):
    n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pairs", type=Path)
    ap.add_argument("--star", type=Path, default=Path(__file__).resolve().parent.parent / "target/release/star")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    cam = [l for l in (args.pairs / "camera.txt").read_text().splitlines() if not l.startswith("#")][0].split()
    w, h = int(cam[0]), int(cam[1])
    fx, fy, cx, cy, depth_scale = map(float, cam[2:7])
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float32)
    gt = {}
    for line in (args.pairs / "pairs.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        v = line.split()
        t = np.array(list(map(float, v[1:4])))
        r = quat_to_rot(*map(float, v[4:8]))
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = r, t
        gt[int(v[0])] = m

    settings = cv2.OdometrySettings()
    settings.setCameraMatrix(k)
    odometry = cv2.Odometry(cv2.OdometryType_RGB, settings, cv2.OdometryAlgoType_COMMON)
    times_ms, t_err_mm, r_err_deg, ok = [], [], [], 0
    for i, keyframe_from_frame in sorted(gt.items()):
        kf = cv2.imread(str(args.pairs / f"kf_{i:04}.png"), cv2.IMREAD_GRAYSCALE)
        kf_depth = cv2.imread(str(args.pairs / f"kf_depth_{i:04}.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / depth_scale
        frame = cv2.imread(str(args.pairs / f"frame_{i:04}.png"), cv2.IMREAD_GRAYSCALE)
        if kf is None or frame is None or kf_depth is None:
            sys.exit(f"pair {i}: cannot read images in {args.pairs}")
        kf_depth[kf_depth <= 0] = np.nan
        start = time.perf_counter()
        src = cv2.OdometryFrame(image=kf, depth=kf_depth)
        dst = cv2.OdometryFrame(image=frame, depth=kf_depth)
        odometry.prepareFrames(src, dst)
        found, rt = odometry.compute(src, dst)
        times_ms.append((time.perf_counter() - start) * 1e3)
        if not found:
            t_err_mm.append(np.inf)
            r_err_deg.append(np.inf)
            continue
        # Rt * src = dst: Rt maps keyframe points into the frame.
        est = np.linalg.inv(rt)
        d = np.linalg.inv(keyframe_from_frame) @ est
        t_err_mm.append(np.linalg.norm(d[:3, 3]) * 1e3)
        r_err_deg.append(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))))
        if t_err_mm[-1] < 10 and r_err_deg[-1] < 0.5:
            ok += 1
    n = len(times_ms)
    print(f"OpenCV {cv2.__version__} RGB odometry on {n} pairs, {w}x{h}, one thread:")
    print(f"  per-pair time: median {np.median(times_ms):.2f} ms, p99 {np.percentile(times_ms, 99):.2f} ms")
    print(f"  error: median {np.median(t_err_mm):.2f} mm, {np.median(r_err_deg):.3f} deg; converged (< 1 cm and < 0.5 deg): {ok}/{n}")
    sys.stdout.flush()
    subprocess.run([str(args.star), "bench", "track", str(args.pairs)], check=True)


if __name__ == "__main__":
    main()
