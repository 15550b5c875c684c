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
pub mod building;
mod objects;
mod params;

use std::sync::Arc;

use build::{Face, MeshBuilder, UvMap};
use objects::{add_box, place_boxes};

pub use objects::SceneBox;
pub use params::{SceneParams, SceneParamsError};

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
    /// The floor plan of a building scene ([`building`]); `None` for the
    /// one room.
    pub plan: Option<Arc<building::FloorPlan>>,
}

impl Scene {
    /// True when `p_world` is inside the room (or a building's rooms,
    /// corridor and doorways) by at least `margin_m` from walls, floor and
    /// ceiling, and at least `margin_m` outside every furniture box and
    /// occluder.
    pub fn is_free(&self, p_world: [f64; 3], margin_m: f64) -> bool {
        let inside = match &self.plan {
            Some(plan) => plan.is_free(p_world, margin_m),
            None => (0..3)
                .all(|k| p_world[k] >= margin_m && p_world[k] <= self.room_size_m[k] - margin_m),
        };
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
    let texture_root = SplitMix64::new(params.texture_seed.unwrap_or(params.seed));

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
                let seed = texture_root.fork(100 + i as u64).next_u64();
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
        plan: None,
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

/// Diffuse shading factor (0..1) of a surface with normal `n`: ambient plus
/// two fixed directional lights.
pub(super) fn lambert(n: [f64; 3]) -> f64 {
    let light = |l: [f64; 3]| {
        let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        ((n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / norm).max(0.0)
    };
    0.62 + 0.22 * light([0.3, 0.5, 0.8]) + 0.14 * light([-0.6, -0.25, 0.75])
}

#[cfg(test)]
pub(crate) mod tests;
