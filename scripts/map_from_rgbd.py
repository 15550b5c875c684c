#!/usr/bin/env python3
"""A colored mesh map (PLY) from an RGB-D sequence with poses, by TSDF fusion.

    map_from_rgbd.py DATASET OUT.ply [--voxel-m 0.02] [--every 2] ...

DATASET is in TUM layout, as `star synth` writes it:
  rgb.txt, depth.txt     "timestamp path" lines (# comments); color or gray
                         8-bit images, 16-bit depth PNGs
  groundtruth.txt        "timestamp tx ty tz qx qy qz qw" (world_from_camera)
  camera.toml            width, height, fx, fy, cx, cy, depth_scale (units
                         per meter) and [distortion] k1 k2 p1 p2 k3 (OpenCV)

Each depth frame is paired with the color frame and the pose nearest in time
(within --max-dt-s); images are undistorted (color bilinear, depth nearest);
the frames are fused by Open3D's UniformTSDFVolume tile by tile with the
same code that builds `star synth --preset scanned` maps (tsdf_fuse.fuse, next
to this script; Open3D's ScalableTSDFVolume returned an empty mesh on this
machine's build). The mesh is in the frame of the poses (the world frame of
groundtruth.txt) and written as binary PLY with uchar vertex colors, which
`star` reads as `map.mesh` directly; if the poses are not z-up, `star map
align OUT.ply` writes the [map.world_from_mesh] that levels it.

Needs the venv's open3d, numpy and opencv (hil_tests/requirements.txt).
"""

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tsdf_fuse  # noqa: E402  (next to this script)


def read_list(path):
    """`timestamp rest...` lines of a TUM list, comments skipped."""
    rows = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        rows.append((float(parts[0]), parts[1:]))
    if not rows:
        raise SystemExit(f"error: {path}: no entries")
    return rows


def nearest(stamps, t):
    """Index of the stamp nearest to t (stamps sorted)."""
    i = int(np.searchsorted(stamps, t))
    best = [k for k in (i - 1, i) if 0 <= k < len(stamps)]
    return min(best, key=lambda k: abs(stamps[k] - t))


def pose_matrix(v):
    tx, ty, tz, qx, qy, qz, qw = (float(x) for x in v)
    m = np.eye(4)
    m[:3, :3] = o3d.geometry.get_rotation_matrix_from_quaternion([qw, qx, qy, qz])
    m[:3, 3] = [tx, ty, tz]
    return m


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("output", type=Path, help="the mesh, .ply")
    ap.add_argument("--voxel-m", type=float, default=0.02, help="TSDF voxel edge (default 0.02)")
    ap.add_argument("--sdf-trunc-voxels", type=float, default=4.0, help="truncation, voxels (default 4)")
    ap.add_argument("--depth-trunc-m", type=float, default=4.0, help="largest depth fused (default 4 m)")
    ap.add_argument("--every", type=int, default=1, help="fuse every n-th frame (default 1)")
    ap.add_argument("--max-frames", type=int, default=0, help="fuse at most this many (0: all)")
    ap.add_argument("--max-dt-s", type=float, default=0.02, help="pairing tolerance (default 0.02 s)")
    ap.add_argument("--tile-m", type=float, default=1.5, help="TSDF tile edge (default 1.5 m)")
    args = ap.parse_args()
    t0 = time.monotonic()

    ds = args.dataset
    with open(ds / "camera.toml", "rb") as f:
        cam = tomllib.load(f)
    w, h = int(cam["width"]), int(cam["height"])
    k = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]], dtype=np.float64)
    d = cam.get("distortion", {})
    dist = np.array([d.get(key, 0.0) for key in ("k1", "k2", "p1", "p2", "k3")], dtype=np.float64)
    depth_scale = float(cam.get("depth_scale", 5000.0))

    rgb = read_list(ds / "rgb.txt")
    depth = read_list(ds / "depth.txt")
    gt = read_list(ds / "groundtruth.txt")
    rgb_t = np.array([t for t, _ in rgb])
    gt_t = np.array([t for t, _ in gt])
    pairs = []
    for t, (depth_file, *_) in depth:
        i, j = nearest(rgb_t, t), nearest(gt_t, t)
        if abs(rgb_t[i] - t) <= args.max_dt_s and abs(gt_t[j] - t) <= args.max_dt_s:
            pairs.append((rgb[i][1][0], depth_file, pose_matrix(gt[j][1])))
    pairs = pairs[:: max(1, args.every)]
    if args.max_frames > 0:
        pairs = pairs[: args.max_frames]
    if not pairs:
        raise SystemExit(f"error: {ds}: no depth frame has a color frame and a pose within {args.max_dt_s} s")

    undistort = bool(np.any(dist != 0.0))
    if undistort:
        map_x, map_y = cv2.initUndistortRectifyMap(k, dist, None, k, (w, h), cv2.CV_32FC1)
    colors, depths, poses = [], [], []
    for color_file, depth_file, pose in pairs:
        color = cv2.imread(str(ds / color_file), cv2.IMREAD_UNCHANGED)
        dep = cv2.imread(str(ds / depth_file), cv2.IMREAD_UNCHANGED)
        if color is None or dep is None:
            raise SystemExit(f"error: cannot read {ds / color_file} or {ds / depth_file}")
        if color.ndim == 3:
            color = cv2.cvtColor(color[:, :, :3], cv2.COLOR_BGR2RGB)
        if color.shape[:2] != (h, w) or dep.shape != (h, w) or dep.dtype != np.uint16:
            raise SystemExit(
                f"error: {color_file} / {depth_file}: expected {w}x{h} 8-bit color and 16-bit depth, "
                f"found {color.shape} {color.dtype} and {dep.shape} {dep.dtype}"
            )
        if undistort:
            color = cv2.remap(color, map_x, map_y, cv2.INTER_LINEAR)
            dep = cv2.remap(dep, map_x, map_y, cv2.INTER_NEAREST)
        colors.append(color)
        depths.append(dep)
        poses.append(pose)
    colors = np.stack(colors)
    depths = np.stack(depths)
    poses = np.stack(poses)

    # The box the tiles cover: the depth points' extent.
    step = 8
    points = []
    for dep, pose in zip(depths, poses):
        z = dep[::step, ::step].astype(np.float64) / depth_scale
        v, u = np.nonzero((z > 0) & (z <= args.depth_trunc_m))
        z = z[v, u]
        x = (u * step - cam["cx"]) / cam["fx"] * z
        y = (v * step - cam["cy"]) / cam["fy"] * z
        points.append(np.stack([x, y, z], axis=1) @ pose[:3, :3].T + pose[:3, 3])
    points = np.concatenate(points)
    if points.size == 0:
        raise SystemExit("error: no depth within --depth-trunc-m in any frame")
    margin = 4 * args.voxel_m
    lo = np.percentile(points, 0.05, axis=0) - margin
    hi = np.percentile(points, 99.95, axis=0) + margin

    job = {
        "width": w,
        "height": h,
        "fx": float(cam["fx"]),
        "fy": float(cam["fy"]),
        "cx": float(cam["cx"]),
        "cy": float(cam["cy"]),
        "depth_scale": depth_scale,
        "depth_trunc_m": args.depth_trunc_m,
        "voxel_m": args.voxel_m,
        "sdf_trunc_m": args.sdf_trunc_voxels * args.voxel_m,
        "tile_m": args.tile_m,
        "overlap_voxels": 3,
        "bounds_min": lo.tolist(),
        "bounds_max": hi.tolist(),
        "assign_step_px": 4,
        "assign_min_points": 16,
    }
    vertices, vertex_colors, triangles, stats = tsdf_fuse.fuse(job, colors, depths, poses)
    if triangles.shape[0] == 0:
        raise SystemExit("error: the fusion produced an empty mesh (no overlapping depth?)")
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices.astype(np.float64)),
        o3d.utility.Vector3iVector(triangles.astype(np.int32)),
    )
    mesh.vertex_colors = o3d.utility.Vector3dVector(vertex_colors.astype(np.float64))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    if not o3d.io.write_triangle_mesh(str(args.output), mesh, write_ascii=False, write_vertex_normals=False):
        raise SystemExit(f"error: cannot write {args.output}")
    stats["frames"] = len(pairs)
    stats["undistorted"] = undistort
    stats["wall_s"] = time.monotonic() - t0
    print(json.dumps(stats))
    print(
        f"map_from_rgbd: {len(pairs)} frames fused into {stats['triangles']} triangles "
        f"({args.voxel_m} m voxels) in {stats['wall_s']:.1f} s: {args.output}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
