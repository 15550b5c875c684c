//! The procedural indoor scene: a textured room with furniture, built from
//! a seed, as two meshes: the `map` the tracker localizes against (with
//! unmapped holes, without occluders) and the `truth` the synthetic camera
//! renders (no holes, with occluders: objects absent from the map).
//!
//! World frame: meters, origin at a floor corner of the room, `x` along the
//! room's length (`room_size_m[0]`), `y` along its width (`room_size_m[1]`),
//! `z` up; the floor is `z = 0` and the ceiling `z = room_size_m[2]`.
//!
//! Takes [`SceneParams`]; gives out a [`Scene`]. Floor, ceiling and the
//! four walls are split into ~0.5 m patches of 4x4 cells (holes remove
//! whole patches, chosen from the seed), furniture and occluders are boxes
//! standing on the floor (random size, position and yaw, no overlap).
//! Each room surface has its own texture; furniture and occluder faces map
//! to random parts of two shared atlases. Vertex gray carries soft shading
//! (two directional lights and darkening near room edges). Same seed, same
//! meshes, bit for bit, on every platform.

mod build;

use build::{Face, MeshBuilder, UvMap};

use super::texture::{paint_surface, SplitMix64, SurfaceKind};
use crate::map::Mesh;

/// Nominal edge length of a hole patch on room surfaces, meters.
pub const PATCH_M: f64 = 0.5;
/// Distance from walls, floor and ceiling of the free-flight box, meters.
pub const FREE_MARGIN_M: f64 = 0.4;
/// Furniture atlas size (square), meters.
const FURNITURE_ATLAS_M: f64 = 4.0;
/// Occluder atlas size, meters.
const OCCLUDER_ATLAS_M: [f64; 2] = [2.0, 4.0];

/// Parameters of a synthetic scene. `Default` is an 8 x 6 x 3 m room with
/// 6 furniture boxes, 2 occluders and 5 % of the map's patches removed.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneParams {
    /// Seed of every random choice (layout, holes, textures).
    pub seed: u64,
    /// Room size `[x, y, z]` in meters (x/y floor, z height).
    pub room_size_m: [f64; 3],
    /// Number of furniture boxes on the floor (fewer when they do not fit).
    pub boxes: usize,
    /// Texture resolution, texels per meter of surface.
    pub texture_px_per_m: f64,
    /// Fraction (0..=1) of the room-surface patches removed from the map.
    pub hole_fraction: f64,
    /// Number of objects present in the truth mesh but absent from the map.
    pub occluders: usize,
}

impl Default for SceneParams {
    fn default() -> Self {
        Self {
            seed: 1,
            room_size_m: [8.0, 6.0, 3.0],
            boxes: 6,
            texture_px_per_m: 128.0,
            hole_fraction: 0.05,
            occluders: 2,
        }
    }
}

/// Invalid [`SceneParams`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneParamsError {
    /// A field is out of its range.
    #[error("scene parameter {field} = {value} is invalid: expected {expected}")]
    OutOfRange {
        /// The field name.
        field: &'static str,
        /// The value found.
        value: f64,
        /// The accepted range.
        expected: &'static str,
    },
}

impl SceneParams {
    /// Checks ranges: room sides 2..=50 m (height 2..=10 m), resolution
    /// 8..=1024 texels/m, hole fraction 0..=0.9, at most 100 boxes and 100
    /// occluders. [`build_scene`] clamps out-of-range values instead.
    pub fn validate(&self) -> Result<(), SceneParamsError> {
        let check = |field, value: f64, lo: f64, hi: f64, expected| {
            if (lo..=hi).contains(&value) {
                Ok(())
            } else {
                Err(SceneParamsError::OutOfRange {
                    field,
                    value,
                    expected,
                })
            }
        };
        check("room_size_m[0]", self.room_size_m[0], 2.0, 50.0, "2..=50 m")?;
        check("room_size_m[1]", self.room_size_m[1], 2.0, 50.0, "2..=50 m")?;
        check("room_size_m[2]", self.room_size_m[2], 2.0, 10.0, "2..=10 m")?;
        check(
            "texture_px_per_m",
            self.texture_px_per_m,
            8.0,
            1024.0,
            "8..=1024",
        )?;
        check("hole_fraction", self.hole_fraction, 0.0, 0.9, "0..=0.9")?;
        check("boxes", self.boxes as f64, 0.0, 100.0, "0..=100")?;
        check("occluders", self.occluders as f64, 0.0, 100.0, "0..=100")
    }

    /// A copy with every field clamped into its valid range (NaN becomes
    /// the default).
    pub fn clamped(&self) -> Self {
        let d = Self::default();
        let clamp =
            |v: f64, lo: f64, hi: f64, def: f64| if v.is_nan() { def } else { v.clamp(lo, hi) };
        Self {
            seed: self.seed,
            room_size_m: [
                clamp(self.room_size_m[0], 2.0, 50.0, d.room_size_m[0]),
                clamp(self.room_size_m[1], 2.0, 50.0, d.room_size_m[1]),
                clamp(self.room_size_m[2], 2.0, 10.0, d.room_size_m[2]),
            ],
            boxes: self.boxes.min(100),
            texture_px_per_m: clamp(self.texture_px_per_m, 8.0, 1024.0, d.texture_px_per_m),
            hole_fraction: clamp(self.hole_fraction, 0.0, 0.9, d.hole_fraction),
            occluders: self.occluders.min(100),
        }
    }
}

/// A box standing on the floor, rotated about `z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBox {
    /// Footprint center `[x, y]`, meters.
    pub center_xy_m: [f64; 2],
    /// Half extents along the box's own x and y axes, meters.
    pub half_size_m: [f64; 2],
    /// Height above the floor, meters.
    pub height_m: f64,
    /// `[cos(yaw), sin(yaw)]` of the box's x axis in the world.
    pub yaw_cos_sin: [f64; 2],
}

impl SceneBox {
    /// True when `p_world` is inside the box grown by `margin_m`.
    pub fn contains(&self, p_world: [f64; 3], margin_m: f64) -> bool {
        let dx = p_world[0] - self.center_xy_m[0];
        let dy = p_world[1] - self.center_xy_m[1];
        let [c, s] = self.yaw_cos_sin;
        let (lx, ly) = (c * dx + s * dy, -s * dx + c * dy);
        lx.abs() < self.half_size_m[0] + margin_m
            && ly.abs() < self.half_size_m[1] + margin_m
            && p_world[2] < self.height_m + margin_m
    }

    /// Radius of the footprint's circumscribed circle.
    pub fn radius_m(&self) -> f64 {
        (self.half_size_m[0] * self.half_size_m[0] + self.half_size_m[1] * self.half_size_m[1])
            .sqrt()
    }
}

/// A synthetic scene: the map, the camera's truth, and its free space.
#[derive(Debug, Clone)]
pub struct Scene {
    /// What the tracker gets: holes removed, no occluders.
    pub map: Mesh,
    /// What the camera sees: no holes, with occluders.
    pub truth: Mesh,
    /// Lower corner of the box where cameras may fly (room shrunk by
    /// [`FREE_MARGIN_M`]); use [`Scene::is_free`] to also avoid furniture.
    pub free_min_m: [f64; 3],
    /// Upper corner of the free-flight box.
    pub free_max_m: [f64; 3],
    /// Room size `[x, y, z]`, meters (the room spans `0..size` per axis).
    pub room_size_m: [f64; 3],
    /// Furniture boxes (in both meshes).
    pub furniture: Vec<SceneBox>,
    /// Occluders (in `truth` only).
    pub occluders: Vec<SceneBox>,
}

impl Scene {
    /// True when `p_world` is inside the room by at least `margin_m` from
    /// walls, floor and ceiling, and at least `margin_m` outside every
    /// furniture box and occluder.
    pub fn is_free(&self, p_world: [f64; 3], margin_m: f64) -> bool {
        let inside =
            (0..3).all(|k| p_world[k] >= margin_m && p_world[k] <= self.room_size_m[k] - margin_m);
        inside
            && !self
                .furniture
                .iter()
                .chain(&self.occluders)
                .any(|b| b.contains(p_world, margin_m))
    }
}

/// The scene for `SceneParams::default()`.
pub fn default_scene() -> Scene {
    build_scene(&SceneParams::default())
}

/// Builds the scene for `params` (clamped into range, see
/// [`SceneParams::clamped`]). Deterministic in the parameters.
pub fn build_scene(params: &SceneParams) -> Scene {
    let params = params.clamped();
    let [lx, ly, lz] = params.room_size_m;
    let root = SplitMix64::new(params.seed);

    let mut layout_rng = root.fork(1);
    let furniture = place_boxes(&mut layout_rng, &params, &[], params.boxes, false);
    let occluders = place_boxes(&mut layout_rng, &params, &furniture, params.occluders, true);
    if furniture.len() < params.boxes || occluders.len() < params.occluders {
        tracing::warn!(
            furniture = furniture.len(),
            occluders = occluders.len(),
            "not every requested box fits in the room"
        );
    }

    let surfaces = room_faces(params.room_size_m);
    let mut kinds: Vec<(SurfaceKind, f64, f64)> = surfaces
        .iter()
        .map(|(kind, f)| (*kind, f.u_len_m, f.v_len_m))
        .collect();
    let furniture_texture = kinds.len();
    kinds.push((SurfaceKind::Furniture, FURNITURE_ATLAS_M, FURNITURE_ATLAS_M));
    let occluder_texture = kinds.len();
    kinds.push((
        SurfaceKind::Occluder,
        OCCLUDER_ATLAS_M[0],
        OCCLUDER_ATLAS_M[1],
    ));
    let textures: Vec<_> = {
        use rayon::prelude::*;
        kinds
            .par_iter()
            .enumerate()
            .map(|(i, &(kind, w, h))| {
                let seed = root.fork(100 + i as u64).next_u64();
                paint_surface(kind, w, h, params.texture_px_per_m, seed)
            })
            .collect()
    };

    // Holes: whole patches of room surfaces, chosen by a seeded shuffle.
    let patch_counts: Vec<[usize; 2]> = surfaces
        .iter()
        .map(|(_, f)| [patches(f.u_len_m), patches(f.v_len_m)])
        .collect();
    let total: usize = patch_counts.iter().map(|[a, b]| a * b).sum();
    let mut order: Vec<usize> = (0..total).collect();
    let mut hole_rng = root.fork(2);
    for i in (1..order.len()).rev() {
        order.swap(i, hole_rng.below(i + 1));
    }
    let hole_count = (params.hole_fraction * total as f64).round() as usize;
    let mut is_hole = vec![false; total];
    for &i in order.iter().take(hole_count) {
        is_hole[i] = true;
    }

    let mut map = MeshBuilder::new(kinds.len());
    let mut truth = MeshBuilder::new(kinds.len());
    let room = params.room_size_m;
    let mut patch_id = 0;
    for (t, ((_, face), [nu, nv])) in surfaces.iter().zip(&patch_counts).enumerate() {
        let uv = UvMap {
            offset: [0.0, 0.0],
            scale: [1.0 / face.u_len_m, 1.0 / face.v_len_m],
        };
        let shade = |p: [f64; 3]| lambert(face.normal) * room_occlusion(p, room);
        let (du, dv) = (face.u_len_m / *nu as f64, face.v_len_m / *nv as f64);
        for j in 0..*nv {
            for i in 0..*nu {
                let s = [i as f64 * du, (i + 1) as f64 * du];
                let tt = [j as f64 * dv, (j + 1) as f64 * dv];
                let cells = [
                    (du / build::CELL_M).round() as usize,
                    (dv / build::CELL_M).round() as usize,
                ];
                truth.grid(face, s, tt, cells, t, uv, &shade);
                if !is_hole[patch_id] {
                    map.grid(face, s, tt, cells, t, uv, &shade);
                }
                patch_id += 1;
            }
        }
    }
    let mut face_rng = root.fork(3);
    for b in &furniture {
        for builder in [&mut map, &mut truth] {
            let mut rng = face_rng.clone();
            add_box(
                builder,
                b,
                furniture_texture,
                [FURNITURE_ATLAS_M; 2],
                &mut rng,
            );
        }
        face_rng = face_rng.fork(4);
    }
    for b in &occluders {
        add_box(
            &mut truth,
            b,
            occluder_texture,
            OCCLUDER_ATLAS_M,
            &mut face_rng,
        );
    }

    let mut map = map.finish();
    let mut truth = truth.finish();
    map.textures = textures[..occluder_texture].to_vec();
    truth.textures = textures;
    Scene {
        map,
        truth,
        free_min_m: [FREE_MARGIN_M; 3],
        free_max_m: [lx - FREE_MARGIN_M, ly - FREE_MARGIN_M, lz - FREE_MARGIN_M],
        room_size_m: params.room_size_m,
        furniture,
        occluders,
    }
}

/// Number of hole patches along a side.
fn patches(len_m: f64) -> usize {
    ((len_m / PATCH_M).round() as usize).max(1)
}

/// Floor, ceiling and four walls, each with its texture axes. Walls run
/// their texture `y` downward from the ceiling.
fn room_faces([lx, ly, lz]: [f64; 3]) -> Vec<(SurfaceKind, Face)> {
    let face = |origin, u_axis, v_axis, u_len_m, v_len_m, normal| Face {
        origin,
        u_axis,
        v_axis,
        u_len_m,
        v_len_m,
        normal,
    };
    let down = [0.0, 0.0, -1.0];
    vec![
        (
            SurfaceKind::Floor,
            face(
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                lx,
                ly,
                [0.0, 0.0, 1.0],
            ),
        ),
        (
            SurfaceKind::Ceiling,
            face(
                [0.0, 0.0, lz],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                lx,
                ly,
                [0.0, 0.0, -1.0],
            ),
        ),
        (
            SurfaceKind::Wall,
            face(
                [0.0, 0.0, lz],
                [1.0, 0.0, 0.0],
                down,
                lx,
                lz,
                [0.0, 1.0, 0.0],
            ),
        ),
        (
            SurfaceKind::Wall,
            face(
                [lx, 0.0, lz],
                [0.0, 1.0, 0.0],
                down,
                ly,
                lz,
                [-1.0, 0.0, 0.0],
            ),
        ),
        (
            SurfaceKind::Wall,
            face(
                [lx, ly, lz],
                [-1.0, 0.0, 0.0],
                down,
                lx,
                lz,
                [0.0, -1.0, 0.0],
            ),
        ),
        (
            SurfaceKind::Wall,
            face(
                [0.0, ly, lz],
                [0.0, -1.0, 0.0],
                down,
                ly,
                lz,
                [1.0, 0.0, 0.0],
            ),
        ),
    ]
}

/// Diffuse shading factor (0..1) of a surface with normal `n`: ambient plus
/// two fixed directional lights.
fn lambert(n: [f64; 3]) -> f64 {
    let light = |l: [f64; 3]| {
        let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        ((n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / norm).max(0.0)
    };
    0.62 + 0.22 * light([0.3, 0.5, 0.8]) + 0.14 * light([-0.6, -0.25, 0.75])
}

/// Darkening near the room's edges and corners: 1 away from them, down to
/// 0.8 where two room surfaces meet.
fn room_occlusion(p: [f64; 3], room: [f64; 3]) -> f64 {
    let mut d = [0.0; 6];
    for k in 0..3 {
        d[2 * k] = p[k].abs();
        d[2 * k + 1] = (room[k] - p[k]).abs();
    }
    d.sort_by(f64::total_cmp);
    // d[0] is the point's own surface; d[1] the nearest other one.
    1.0 - 0.2 * (1.0 - (d[1] / 0.35).min(1.0))
}

/// Places up to `count` boxes without overlapping `existing` or each other.
/// Furniture stands against a wall half of the time; occluders are
/// person- or plant-sized and stand in the open.
fn place_boxes(
    rng: &mut SplitMix64,
    params: &SceneParams,
    existing: &[SceneBox],
    count: usize,
    occluder: bool,
) -> Vec<SceneBox> {
    let [lx, ly, _] = params.room_size_m;
    let mut placed: Vec<SceneBox> = Vec::new();
    for _ in 0..count {
        for _attempt in 0..200 {
            let (half, height) = if occluder {
                (
                    [rng.range(0.15, 0.3), rng.range(0.12, 0.25)],
                    rng.range(1.0, 1.85),
                )
            } else {
                (
                    [rng.range(0.25, 0.8), rng.range(0.2, 0.45)],
                    rng.range(0.4, 1.2),
                )
            };
            let against_wall = !occluder && rng.chance(0.5);
            let (center, yaw) = if against_wall {
                let wall = rng.below(4);
                let along = if wall % 2 == 0 { lx } else { ly };
                let t = rng.range(half[0] + 0.05, along - half[0] - 0.05);
                let off = half[1] + 0.02;
                match wall {
                    0 => ([t, off], [1.0, 0.0]),
                    1 => ([lx - off, t], [0.0, 1.0]),
                    2 => ([t, ly - off], [1.0, 0.0]),
                    _ => ([off, t], [0.0, 1.0]),
                }
            } else {
                let r = (half[0] * half[0] + half[1] * half[1]).sqrt() + 0.3;
                let yaw = random_unit(rng);
                ([rng.range(r, lx - r), rng.range(r, ly - r)], yaw)
            };
            let candidate = SceneBox {
                center_xy_m: center,
                half_size_m: half,
                height_m: height,
                yaw_cos_sin: yaw,
            };
            let clear = existing.iter().chain(&placed).all(|o| {
                let dx = o.center_xy_m[0] - center[0];
                let dy = o.center_xy_m[1] - center[1];
                (dx * dx + dy * dy).sqrt() > o.radius_m() + candidate.radius_m() + 0.35
            });
            let inside = center[0] > 0.0 && center[0] < lx && center[1] > 0.0 && center[1] < ly;
            if clear && inside {
                placed.push(candidate);
                break;
            }
        }
    }
    placed
}

/// A random unit vector in the plane, without trigonometry.
fn random_unit(rng: &mut SplitMix64) -> [f64; 2] {
    for _ in 0..32 {
        let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let n = (a * a + b * b).sqrt();
        if n > 0.1 && n <= 1.0 {
            return [a / n, b / n];
        }
    }
    [1.0, 0.0]
}

/// Adds the top and four sides of `b`, each face on a random part of an
/// atlas of `atlas_m` meters.
fn add_box(
    builder: &mut MeshBuilder,
    b: &SceneBox,
    texture: usize,
    atlas_m: [f64; 2],
    rng: &mut SplitMix64,
) {
    let [c, s] = b.yaw_cos_sin;
    let (ex, ey) = ([c, s, 0.0], [-s, c, 0.0]);
    let [hx, hy] = b.half_size_m;
    let h = b.height_m;
    let at = |a: f64, bb: f64, z: f64| {
        [
            b.center_xy_m[0] + a * ex[0] + bb * ey[0],
            b.center_xy_m[1] + a * ex[1] + bb * ey[1],
            z,
        ]
    };
    let neg = |v: [f64; 3]| [-v[0], -v[1], -v[2]];
    let down = [0.0, 0.0, -1.0];
    let faces = [
        Face {
            origin: at(-hx, -hy, h),
            u_axis: ex,
            v_axis: ey,
            u_len_m: 2.0 * hx,
            v_len_m: 2.0 * hy,
            normal: [0.0, 0.0, 1.0],
        },
        Face {
            origin: at(hx, -hy, h),
            u_axis: ey,
            v_axis: down,
            u_len_m: 2.0 * hy,
            v_len_m: h,
            normal: ex,
        },
        Face {
            origin: at(hx, hy, h),
            u_axis: neg(ex),
            v_axis: down,
            u_len_m: 2.0 * hx,
            v_len_m: h,
            normal: ey,
        },
        Face {
            origin: at(-hx, hy, h),
            u_axis: neg(ey),
            v_axis: down,
            u_len_m: 2.0 * hy,
            v_len_m: h,
            normal: neg(ex),
        },
        Face {
            origin: at(-hx, -hy, h),
            u_axis: ex,
            v_axis: down,
            u_len_m: 2.0 * hx,
            v_len_m: h,
            normal: neg(ey),
        },
    ];
    for face in &faces {
        let span = [
            (face.u_len_m / atlas_m[0]).min(1.0),
            (face.v_len_m / atlas_m[1]).min(1.0),
        ];
        let uv = UvMap {
            offset: [rng.range(0.0, 1.0 - span[0]), rng.range(0.0, 1.0 - span[1])],
            scale: [span[0] / face.u_len_m, span[1] / face.v_len_m],
        };
        let top = face.normal[2] > 0.5;
        let shade = |p: [f64; 3]| {
            let floor_dark = if top {
                1.0
            } else {
                1.0 - 0.2 * (1.0 - (p[2] / 0.3).min(1.0))
            };
            lambert(face.normal) * floor_dark
        };
        builder.face(face, texture, uv, &shade);
    }
}

#[cfg(test)]
mod tests;
