//! The building's meshes: each room design's shell built once in its own
//! frame and copied to every room of that design, each room's furniture
//! built in the room's frame, and the corridor built in place.
//!
//! Takes a [`FloorPlan`] and a seed; gives out the `map` mesh (rooms,
//! corridor, furniture) and the `truth` mesh (the map plus occluders), and
//! their textures. Surfaces are cut into cells of `spec.cell_m`; walls
//! leave the doorways open, and each doorway gets its reveal (two jambs,
//! the lintel's underside and the threshold) through the wall's
//! thickness. Vertex gray is shaded in the room's own frame (lights fixed
//! to the room, darkening near the room's edges), so two rooms of one
//! design have the same shell to the last vertex apart from their
//! placement (and the same furniture too with identical rooms).
//!
//! Textures: per texture set a floor, a ceiling and a wall texture, then
//! the corridor's three, the furniture atlas and the occluder atlas, all
//! painted by [`paint_surface`] and repeated across larger surfaces.

use super::super::build::{Face, MeshBuilder, UvMap};
use super::super::objects::add_box;
use super::super::{lambert, room_occlusion};
use super::layout::{FloorPlan, Furnishing, RoomDesign};
use crate::map::{GrayTexture, Mesh};
use crate::rng::SplitMix64;
use crate::synth::texture::{paint_surface, SurfaceKind};

/// Side of the square room floor and ceiling textures, meters.
const ROOM_FLOOR_TEXTURE_M: f64 = 6.0;
/// Length of wall and corridor textures, meters.
const STRIP_TEXTURE_M: f64 = 8.0;
/// Furniture atlas size (square), meters.
const FURNITURE_ATLAS_M: f64 = 4.0;
/// Occluder atlas size, meters.
const OCCLUDER_ATLAS_M: [f64; 2] = [2.0, 4.0];

/// Texture numbers of the building.
struct TextureIds {
    sets: usize,
}

impl TextureIds {
    fn floor(&self, set: usize) -> usize {
        3 * set
    }
    fn ceiling(&self, set: usize) -> usize {
        3 * set + 1
    }
    fn wall(&self, set: usize) -> usize {
        3 * set + 2
    }
    fn corridor(&self) -> usize {
        3 * self.sets
    }
    fn furniture(&self) -> usize {
        3 * self.sets + 3
    }
    fn occluder(&self) -> usize {
        3 * self.sets + 4
    }
    fn count(&self) -> usize {
        3 * self.sets + 5
    }
}

/// The map and truth meshes of `plan` (textures included).
pub(super) fn build_meshes(plan: &FloorPlan, seed: u64) -> (Mesh, Mesh) {
    let spec = &plan.spec;
    let ids = TextureIds {
        sets: spec.texture_sets.max(1),
    };
    let h = spec.height_m;
    let cw = spec.corridor_width_m;
    let mut kinds = Vec::with_capacity(ids.count());
    for _ in 0..ids.sets {
        kinds.push((
            SurfaceKind::Floor,
            ROOM_FLOOR_TEXTURE_M,
            ROOM_FLOOR_TEXTURE_M,
        ));
        kinds.push((
            SurfaceKind::Ceiling,
            ROOM_FLOOR_TEXTURE_M,
            ROOM_FLOOR_TEXTURE_M,
        ));
        kinds.push((SurfaceKind::Wall, STRIP_TEXTURE_M, h));
    }
    kinds.push((SurfaceKind::Floor, STRIP_TEXTURE_M, cw));
    kinds.push((SurfaceKind::Ceiling, STRIP_TEXTURE_M, cw));
    kinds.push((SurfaceKind::Wall, STRIP_TEXTURE_M, h));
    kinds.push((SurfaceKind::Furniture, FURNITURE_ATLAS_M, FURNITURE_ATLAS_M));
    kinds.push((
        SurfaceKind::Occluder,
        OCCLUDER_ATLAS_M[0],
        OCCLUDER_ATLAS_M[1],
    ));
    let texture_root = SplitMix64::new(seed).fork(7);
    let textures: Vec<GrayTexture> = {
        use rayon::prelude::*;
        kinds
            .par_iter()
            .enumerate()
            .map(|(i, &(kind, w, th))| {
                let s = texture_root.fork(100 + i as u64).next_u64();
                paint_surface(kind, w, th, spec.texture_px_per_m, s)
            })
            .collect()
    };

    // Each design's shell once, in its own frame; each room's furniture in
    // the room's frame, and its occluders apart (truth only). Identical
    // rooms draw their boxes' texture patches from the design's generator,
    // so their furniture is the same to the last vertex too.
    let (shells, boxes): (Vec<Mesh>, Vec<(Mesh, Mesh)>) = {
        use rayon::prelude::*;
        let shells = plan
            .designs
            .par_iter()
            .map(|d| design_shell(plan, d, &ids))
            .collect();
        let boxes = plan
            .rooms
            .par_iter()
            .zip(&plan.furnishings)
            .enumerate()
            .map(|(i, (room, f))| {
                let stream = if spec.identical_rooms {
                    500 + room.design as u64
                } else {
                    5000 + i as u64
                };
                room_boxes(plan, f, &ids, SplitMix64::new(seed).fork(stream))
            })
            .collect();
        (shells, boxes)
    };

    let mut map = MeshBuilder::with_cell(ids.count(), spec.cell_m);
    let mut truth = MeshBuilder::with_cell(ids.count(), spec.cell_m);
    for (room, (furniture, occluders)) in plan.rooms.iter().zip(&boxes) {
        let Some(shell) = shells.get(room.design) else {
            continue;
        };
        let place = |p: [f64; 3]| room.world_from_room(p);
        map.append(shell, &place);
        map.append(furniture, &place);
        truth.append(shell, &place);
        truth.append(furniture, &place);
        truth.append(occluders, &place);
    }
    for builder in [&mut map, &mut truth] {
        corridor(builder, plan, &ids);
    }
    let mut map = map.finish();
    let mut truth = truth.finish();
    map.textures = textures[..ids.occluder()].to_vec();
    truth.textures = textures;
    (map, truth)
}

/// A face with its texture axes.
fn face(origin: [f64; 3], u: [f64; 3], v: [f64; 3], len: [f64; 2], normal: [f64; 3]) -> Face {
    Face {
        origin,
        u_axis: u,
        v_axis: v,
        u_len_m: len[0],
        v_len_m: len[1],
        normal,
    }
}

/// Cells along a span of `len_m`.
fn cells(len_m: f64, cell_m: f64) -> usize {
    ((len_m / cell_m).round() as usize).max(1)
}

/// Adds `f` over `s` x `t` with cells of the builder's size.
fn part(
    b: &mut MeshBuilder,
    f: &Face,
    s: [f64; 2],
    t: [f64; 2],
    texture: usize,
    uv: UvMap,
    shade: &dyn Fn([f64; 3]) -> f64,
) {
    if s[1] - s[0] <= 1e-9 || t[1] - t[0] <= 1e-9 {
        return;
    }
    let c = b.cell_m();
    b.grid(
        f,
        s,
        t,
        [cells(s[1] - s[0], c), cells(t[1] - t[0], c)],
        texture,
        uv,
        shade,
    );
}

/// A wall (`f`, its `v` axis down from the ceiling) with doorways over the
/// `openings` (ranges of `s`, sorted) up to `door_height_m`.
#[allow(clippy::too_many_arguments)]
fn wall(
    b: &mut MeshBuilder,
    f: &Face,
    openings: &[[f64; 2]],
    door_height_m: f64,
    texture: usize,
    uv: UvMap,
    shade: &dyn Fn([f64; 3]) -> f64,
) {
    let h = f.v_len_m;
    let mut s0 = 0.0;
    for &[a, e] in openings {
        part(b, f, [s0, a], [0.0, h], texture, uv, shade);
        part(b, f, [a, e], [0.0, h - door_height_m], texture, uv, shade);
        s0 = e;
    }
    part(b, f, [s0, f.u_len_m], [0.0, h], texture, uv, shade);
}

fn repeat(u_m: f64, v_m: f64) -> UvMap {
    UvMap {
        offset: [0.0, 0.0],
        scale: [1.0 / u_m, 1.0 / v_m],
    }
}

/// One design's shell (floor, ceiling, walls, doorway), room frame.
fn design_shell(plan: &FloorPlan, d: &RoomDesign, ids: &TextureIds) -> Mesh {
    let spec = &plan.spec;
    let [w, depth] = d.size_m;
    let h = spec.height_m;
    let t = spec.wall_thickness_m;
    let (dw, dh) = (spec.door_width_m, spec.door_height_m);
    let set = d.texture_set;
    let mut b = MeshBuilder::with_cell(ids.count(), spec.cell_m);
    let room = [w, depth, h];
    let lit = |n: [f64; 3]| move |p: [f64; 3]| lambert(n) * room_occlusion(p, room);
    let down = [0.0, 0.0, -1.0];
    let floor_uv = repeat(ROOM_FLOOR_TEXTURE_M, ROOM_FLOOR_TEXTURE_M);
    let wall_uv = repeat(STRIP_TEXTURE_M, h);
    let up = [0.0, 0.0, 1.0];
    let floor = face([0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [w, depth], up);
    part(
        &mut b,
        &floor,
        [0.0, w],
        [0.0, depth],
        ids.floor(set),
        floor_uv,
        &lit(up),
    );
    let ceiling = face(
        [0.0, 0.0, h],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [w, depth],
        down,
    );
    part(
        &mut b,
        &ceiling,
        [0.0, w],
        [0.0, depth],
        ids.ceiling(set),
        floor_uv,
        &lit(down),
    );
    let door = [d.door_center_m - 0.5 * dw, d.door_center_m + 0.5 * dw];
    let walls = [
        // Door wall, facing into the room (+y).
        (
            face(
                [0.0, 0.0, h],
                [1.0, 0.0, 0.0],
                down,
                [w, h],
                [0.0, 1.0, 0.0],
            ),
            Some(door),
        ),
        (
            face(
                [w, 0.0, h],
                [0.0, 1.0, 0.0],
                down,
                [depth, h],
                [-1.0, 0.0, 0.0],
            ),
            None,
        ),
        (
            face(
                [w, depth, h],
                [-1.0, 0.0, 0.0],
                down,
                [w, h],
                [0.0, -1.0, 0.0],
            ),
            None,
        ),
        (
            face(
                [0.0, depth, h],
                [0.0, -1.0, 0.0],
                down,
                [depth, h],
                [1.0, 0.0, 0.0],
            ),
            None,
        ),
    ];
    for (f, opening) in &walls {
        let openings: Vec<[f64; 2]> = opening.iter().copied().collect();
        wall(
            &mut b,
            f,
            &openings,
            dh,
            ids.wall(set),
            wall_uv,
            &lit(f.normal),
        );
    }
    // The doorway's reveal through the wall (y from -t to 0).
    let [a, e] = door;
    let reveal = [
        face(
            [a, 0.0, dh],
            [0.0, -1.0, 0.0],
            down,
            [t, dh],
            [1.0, 0.0, 0.0],
        ),
        face(
            [e, -t, dh],
            [0.0, 1.0, 0.0],
            down,
            [t, dh],
            [-1.0, 0.0, 0.0],
        ),
        face(
            [a, 0.0, dh],
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [dw, t],
            down,
        ),
    ];
    for f in &reveal {
        part(
            &mut b,
            f,
            [0.0, f.u_len_m],
            [0.0, f.v_len_m],
            ids.wall(set),
            wall_uv,
            &lit(f.normal),
        );
    }
    let threshold = face([a, -t, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [dw, t], up);
    part(
        &mut b,
        &threshold,
        [0.0, dw],
        [0.0, t],
        ids.floor(set),
        floor_uv,
        &lit(up),
    );
    b.finish()
}

/// One room's furniture, and its occluders apart, room frame; texture
/// patches drawn from `rng`.
fn room_boxes(
    plan: &FloorPlan,
    f: &Furnishing,
    ids: &TextureIds,
    mut rng: SplitMix64,
) -> (Mesh, Mesh) {
    let cell_m = plan.spec.cell_m;
    let mut b = MeshBuilder::with_cell(ids.count(), cell_m);
    for bx in &f.furniture {
        add_box(
            &mut b,
            bx,
            ids.furniture(),
            [FURNITURE_ATLAS_M; 2],
            &mut rng,
        );
    }
    let mut o = MeshBuilder::with_cell(ids.count(), cell_m);
    for bx in &f.occluders {
        add_box(&mut o, bx, ids.occluder(), OCCLUDER_ATLAS_M, &mut rng);
    }
    (b.finish(), o.finish())
}

/// The corridor, world frame: floor, ceiling, two long walls with the
/// rooms' doorways, two end walls.
fn corridor(b: &mut MeshBuilder, plan: &FloorPlan, ids: &TextureIds) {
    let spec = &plan.spec;
    let [x0, y0] = plan.corridor_min_m;
    let [x1, y1] = plan.corridor_max_m;
    let (len, cw, h) = (x1 - x0, y1 - y0, spec.height_m);
    let box_size = [len, cw, h];
    let lit = |n: [f64; 3]| {
        move |p: [f64; 3]| lambert(n) * room_occlusion([p[0] - x0, p[1] - y0, p[2]], box_size)
    };
    let (floor_t, ceiling_t, wall_t) = (ids.corridor(), ids.corridor() + 1, ids.corridor() + 2);
    let down = [0.0, 0.0, -1.0];
    let up = [0.0, 0.0, 1.0];
    let strip_uv = repeat(STRIP_TEXTURE_M, cw);
    let wall_uv = repeat(STRIP_TEXTURE_M, h);
    let floor = face(
        [x0, y0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [len, cw],
        up,
    );
    part(
        b,
        &floor,
        [0.0, len],
        [0.0, cw],
        floor_t,
        strip_uv,
        &lit(up),
    );
    let ceiling = face(
        [x0, y0, h],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [len, cw],
        down,
    );
    part(
        b,
        &ceiling,
        [0.0, len],
        [0.0, cw],
        ceiling_t,
        strip_uv,
        &lit(down),
    );
    // Doorways: x ranges on the south (y0) and north (y1) walls.
    let half = 0.5 * spec.door_width_m;
    let mut south = Vec::new();
    let mut north = Vec::new();
    for room in &plan.rooms {
        let Some(d) = plan.designs.get(room.design) else {
            continue;
        };
        let x = room.world_from_room([d.door_center_m, 0.0, 0.0])[0];
        if room.turned {
            south.push([x - half - x0, x + half - x0]);
        } else {
            // The north wall runs from x1 toward x0.
            north.push([x1 - x - half, x1 - x + half]);
        }
    }
    south.sort_by(|a, b| a[0].total_cmp(&b[0]));
    north.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let dh = spec.door_height_m;
    let south_wall = face(
        [x0, y0, h],
        [1.0, 0.0, 0.0],
        down,
        [len, h],
        [0.0, 1.0, 0.0],
    );
    wall(
        b,
        &south_wall,
        &south,
        dh,
        wall_t,
        wall_uv,
        &lit(south_wall.normal),
    );
    let north_wall = face(
        [x1, y1, h],
        [-1.0, 0.0, 0.0],
        down,
        [len, h],
        [0.0, -1.0, 0.0],
    );
    wall(
        b,
        &north_wall,
        &north,
        dh,
        wall_t,
        wall_uv,
        &lit(north_wall.normal),
    );
    let end_uv = repeat(STRIP_TEXTURE_M, h);
    for f in [
        face(
            [x0, y1, h],
            [0.0, -1.0, 0.0],
            down,
            [cw, h],
            [1.0, 0.0, 0.0],
        ),
        face(
            [x1, y0, h],
            [0.0, 1.0, 0.0],
            down,
            [cw, h],
            [-1.0, 0.0, 0.0],
        ),
    ] {
        part(b, &f, [0.0, cw], [0.0, h], wall_t, end_uv, &lit(f.normal));
    }
}
