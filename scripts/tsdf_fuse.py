#!/usr/bin/env python3
"""TSDF fusion of an RGB-D scan into a vertex-colored mesh, tile by tile.

`fuse()` does the work; `scripts/map_from_rgbd.py` imports it for a user's
TUM-layout sequence.

`star synth --preset scanned` renders a scanning run (noisy depth, colors under
the scan's light) and calls this script (a copy of it is embedded in the
binary) with a job file:

    tsdf_fuse.py JOB.toml

JOB.toml (written by src/synth/scanned/fusion.rs):
  width, height, fx, fy, cx, cy  the scan camera (ideal pinhole)
  frames                         number of frames
  gray_path                      frames * height * width uint8, row-major
  depth_path                     frames * height * width uint16 (little
                                 endian), millimeters, 0 = no measurement
  mesh_from_camera               frames arrays of 16 floats, row-major 4x4: the
                                 camera pose in the frame the mesh is built in
  depth_scale, depth_trunc_m     units per meter (1000), largest depth used
  voxel_m, sdf_trunc_m           TSDF voxel edge and truncation distance
  tile_m, overlap_voxels         tile (cube) edge and its overlap, voxels
  bounds_min, bounds_max         the box (mesh frame) the tiles cover
  assign_step_px, assign_min_points
                                 how frames are assigned to tiles (below)
  out_prefix                     writes PREFIX.vertices.f32 (x y z per
                                 vertex), PREFIX.colors.f32 (r g b in 0..1),
                                 PREFIX.triangles.u32 (3 indices each), all
                                 little endian, and PREFIX.stats.toml

A uniform 1 cm grid over a whole room is ~1.5e8 voxels (about 7 GB in
Open3D's UniformTSDFVolume), so the box is cut into cubes of `tile_m` on a
grid aligned to the voxel size. Each tile is its own UniformTSDFVolume with
its origin set, extended by `overlap_voxels` on every side so marching cubes
has the neighbours it needs at the seams. A frame is integrated into a tile
only when at least `assign_min_points` of its depth points (one every
`assign_step_px` pixels), grown by overlap + truncation, fall in the tile,
so empty tiles are never allocated and a tile sees only the frames that
observe its surfaces (free-space carving by frames that merely look through
a tile is lost; the scene is static). Each tile's mesh is cropped to its
core (triangles whose centroid lies in [core_min, core_max)) and appended.

Open3D's ScalableTSDFVolume returned an empty mesh on this machine's build,
hence the uniform volumes.
"""

import json
import resource
import sys
import time
import tomllib

import numpy as np
import open3d as o3d


def tiles_of_frame(depth, pose, job, grid_origin, tile, margin, n_tiles):
    """Tile keys (ix, iy, iz) observed by one frame -> their point counts.

    A point counts for every tile within `margin` of it (the 8 corners of
    the cube of half-size `margin` around it)."""
    step = job["assign_step_px"]
    d = depth[::step, ::step].astype(np.float64) / job["depth_scale"]
    v, u = np.nonzero(d > 0)
    if u.size == 0:
        return {}
    z = d[v, u]
    x = (u * step - job["cx"]) / job["fx"] * z
    y = (v * step - job["cy"]) / job["fy"] * z
    p = np.stack([x, y, z], axis=1) @ pose[:3, :3].T + pose[:3, 3]
    counts = {}
    nx, ny, nz = (int(k) for k in n_tiles)
    for ox in (-margin, margin):
        for oy in (-margin, margin):
            for oz in (-margin, margin):
                idx = np.floor((p + [ox, oy, oz] - grid_origin) / tile).astype(np.int64)
                inside = np.all((idx >= 0) & (idx < [nx, ny, nz]), axis=1)
                idx = idx[inside]
                linear = (idx[:, 0] * ny + idx[:, 1]) * nz + idx[:, 2]
                keys, n = np.unique(linear, return_counts=True)
                for k, c in zip(keys.tolist(), n.tolist()):
                    counts[k] = max(counts.get(k, 0), c)
    return {(k // (ny * nz), (k // nz) % ny, k % nz): c for k, c in counts.items()}


class FrameCache:
    """The last `capacity` frames as Open3D RGBD images (tiles next to each
    other share most of their frames)."""

    def __init__(self, color, depth, job, capacity):
        self.color, self.depth, self.job = color, depth, job
        self.capacity = capacity
        self.images = {}
        self.hits = 0
        self.misses = 0

    def get(self, i):
        image = self.images.pop(i, None)
        if image is None:
            self.misses += 1
            frame = np.asarray(self.color[i])
            if frame.ndim == 2:  # gray: the same in R, G and B
                frame = np.repeat(frame[:, :, None], 3, axis=2)
            color = np.ascontiguousarray(frame)
            image = o3d.geometry.RGBDImage.create_from_color_and_depth(
                o3d.geometry.Image(color),
                o3d.geometry.Image(np.ascontiguousarray(self.depth[i]).astype(np.uint16)),
                depth_scale=self.job["depth_scale"],
                depth_trunc=self.job["depth_trunc_m"],
                convert_rgb_to_intensity=False,
            )
            if len(self.images) >= self.capacity:
                # Dicts keep insertion order: the first is the least recent.
                del self.images[next(iter(self.images))]
        else:
            self.hits += 1
        self.images[i] = image
        return image


def to_toml(table):
    """A flat dict of str, int, float and lists of int as TOML."""
    lines = []
    for key, value in table.items():
        # JSON strings, numbers and lists of numbers are valid TOML values.
        lines.append(f"{key} = {json.dumps(value)}")
    return "\n".join(lines) + "\n"


def fuse(job, color, depth, poses):
    """Fuses the frames into one mesh, tile by tile (see the module docs).

    job: the job's camera, TSDF and tile keys (width ... assign_min_points;
    frames, paths and poses are not read from it); color: frames of uint8,
    (n, h, w) gray or (n, h, w, 3) RGB; depth: (n, h, w) uint16 in units of
    depth_scale per meter, 0 = none; poses: (n, 4, 4) mesh_from_camera.
    Returns (vertices float32 (V, 3), colors float32 (V, 3) in 0..1,
    triangles uint32 (T, 3), stats dict)."""
    t_start = time.monotonic()
    w, h, n = job["width"], job["height"], len(poses)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, job["fx"], job["fy"], job["cx"], job["cy"])
    voxel = float(job["voxel_m"])
    trunc = float(job["sdf_trunc_m"])
    overlap_vox = int(job["overlap_voxels"])
    overlap = overlap_vox * voxel
    tile_vox = max(1, int(round(job["tile_m"] / voxel)))
    tile = tile_vox * voxel
    lo = np.floor(np.asarray(job["bounds_min"], dtype=np.float64) / voxel) * voxel
    hi = np.asarray(job["bounds_max"], dtype=np.float64)
    n_tiles = np.maximum(1, np.ceil((hi - lo) / tile)).astype(np.int64)

    # Which frames observe which tile.
    t0 = time.monotonic()
    frames_of_tile = {}
    for i in range(n):
        for key, count in tiles_of_frame(depth[i], poses[i], job, lo, tile, overlap + trunc, n_tiles).items():
            if count >= job["assign_min_points"]:
                frames_of_tile.setdefault(key, []).append(i)
    t_assign = time.monotonic() - t0

    cache = FrameCache(color, depth, job, int(job.get("cache_frames", 48)))
    res = tile_vox + 2 * overlap_vox
    length = res * voxel
    vertices, colors, triangles = [], [], []
    n_vertices = 0
    integrations = 0
    t_integrate = 0.0
    t_extract = 0.0
    for key in sorted(frames_of_tile):
        core_min = lo + np.asarray(key, dtype=np.float64) * tile
        core_max = core_min + tile
        volume = o3d.pipelines.integration.UniformTSDFVolume(
            length, res, trunc, o3d.pipelines.integration.TSDFVolumeColorType.RGB8, core_min - overlap
        )
        t0 = time.monotonic()
        for i in frames_of_tile[key]:
            volume.integrate(cache.get(i), intrinsic, np.linalg.inv(poses[i]))
            integrations += 1
        t1 = time.monotonic()
        mesh = volume.extract_triangle_mesh()
        del volume
        t_extract += time.monotonic() - t1
        t_integrate += t1 - t0
        v = np.asarray(mesh.vertices)
        t = np.asarray(mesh.triangles)
        if t.size == 0:
            continue
        centroid = v[t].mean(axis=1)
        keep = np.all((centroid >= core_min) & (centroid < core_max), axis=1)
        t = t[keep]
        if t.size == 0:
            continue
        used, inverse = np.unique(t.reshape(-1), return_inverse=True)
        vertices.append(v[used].astype(np.float32))
        colors.append(np.asarray(mesh.vertex_colors)[used].astype(np.float32))
        triangles.append((inverse.reshape(-1, 3) + n_vertices).astype(np.uint32))
        n_vertices += used.size

    empty3 = np.zeros((0, 3), dtype=np.float32)
    vertices = np.concatenate(vertices or [empty3])
    colors = np.concatenate(colors or [empty3])
    triangles = np.concatenate(triangles or [np.zeros((0, 3), dtype=np.uint32)])
    stats = {
        "open3d": o3d.__version__,
        "tiles": len(frames_of_tile),
        "tile_grid": [int(k) for k in n_tiles],
        "tile_m": tile,
        "tile_voxels": res,
        "integrations": integrations,
        "frame_cache_hits": cache.hits,
        "frame_cache_misses": cache.misses,
        "vertices": int(n_vertices),
        "triangles": int(triangles.shape[0]),
        "assign_s": t_assign,
        "integrate_s": t_integrate,
        "extract_s": t_extract,
        "total_s": time.monotonic() - t_start,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }
    return vertices, colors, triangles, stats


def main():
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    with open(sys.argv[1], "rb") as f:
        job = tomllib.load(f)
    w, h, n = job["width"], job["height"], job["frames"]
    gray = np.memmap(job["gray_path"], dtype=np.uint8, mode="r", shape=(n, h, w))
    depth = np.memmap(job["depth_path"], dtype="<u2", mode="r", shape=(n, h, w))
    poses = np.asarray(job["mesh_from_camera"], dtype=np.float64).reshape(n, 4, 4)
    vertices, colors, triangles, stats = fuse(job, gray, depth, poses)
    prefix = job["out_prefix"]
    vertices.astype("<f4").tofile(prefix + ".vertices.f32")
    colors.astype("<f4").tofile(prefix + ".colors.f32")
    triangles.astype("<u4").tofile(prefix + ".triangles.u32")
    with open(prefix + ".stats.toml", "w", encoding="utf-8") as f:
        f.write(to_toml(stats))
    print(json.dumps(stats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
