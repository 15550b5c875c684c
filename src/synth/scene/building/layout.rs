//! The floor plan of a building: room designs, where each room stands,
//! the corridor, the doors, and the free space a camera may fly in.
//!
//! Takes a [`BuildingSpec`] and a seed; gives out a [`FloorPlan`]. One
//! straight corridor runs along `x`; rooms stand in a row on each side of
//! it (south: `y` below the corridor, north: above), side by side with a
//! wall's thickness between them, each with one door onto the corridor.
//! Every room is an instance of one of a few [`RoomDesign`]s (size, door
//! position, textures, furniture), described in the room's own frame:
//! `x` along the door wall, `y` away from the corridor, the door wall at
//! `y = 0` and the doorway's reveal at `-wall_thickness_m..0`. North rooms
//! are placed as designed, south rooms turned by 180 degrees, so two rooms
//! of one design have the same shell (size, door, textures, lights)
//! whichever side they stand on. Each room is furnished on its own from
//! the shared furniture atlas ([`Furnishing`]): look-alike, not the same,
//! as rooms of one floor plan are in a real building. With
//! [`BuildingSpec::identical_rooms`] every room takes its design's
//! furniture instead, and two rooms of one design are the same to the last
//! vertex.

use super::super::objects::SceneBox;
use super::furnish::{self, KeepOut};
use super::BuildingSpec;
use crate::rng::SplitMix64;
use crate::synth::trajectory::tour::RoomRoute;

/// Room widths (along the corridor) the designs draw from, meters.
const WIDTHS_M: [f64; 4] = [4.0, 5.0, 6.0, 7.5];
/// Room depths (away from the corridor) the designs draw from, meters.
const DEPTHS_M: [f64; 3] = [5.0, 6.0, 7.0];
/// Distance of the door's middle from a side wall when not centered, m.
const DOOR_FROM_SIDE_M: f64 = 1.4;
/// Distance of the tour's first point inside a room from its door wall, m.
const INSIDE_M: f64 = 1.2;
/// Furniture keeps this far from the tour's path in a room, meters.
const KEEP_OUT_M: f64 = 0.9;

/// One room layout, in the room's own frame (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct RoomDesign {
    /// Floor size: `[along the door wall, away from the corridor]`, m.
    pub size_m: [f64; 2],
    /// Middle of the door along the door wall, m.
    pub door_center_m: f64,
    /// Which of the building's texture sets its floor, ceiling and walls use.
    pub texture_set: usize,
    /// The design's own furnishing (what every room of it gets with
    /// [`BuildingSpec::identical_rooms`]), room frame.
    pub furnishing: Furnishing,
    /// The tour inside the room: in front of the door, then a loop (left,
    /// back, right), room frame.
    pub route_m: [[f64; 2]; 4],
}

/// The boxes standing in one room, room frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Furnishing {
    /// Furniture (map and truth).
    pub furniture: Vec<SceneBox>,
    /// Occluders (truth only).
    pub occluders: Vec<SceneBox>,
}

/// One room of the building: a design placed on the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacedRoom {
    /// Index into [`FloorPlan::designs`].
    pub design: usize,
    /// World corner of the room's floor with the smallest `x` and `y`.
    pub min_m: [f64; 2],
    /// World size `[x, y]` (the design's size).
    pub size_m: [f64; 2],
    /// Turned by 180 degrees (the south row).
    pub turned: bool,
}

impl PlacedRoom {
    /// A room-frame point in the world.
    pub fn world_from_room(&self, p: [f64; 3]) -> [f64; 3] {
        if self.turned {
            [
                self.min_m[0] + self.size_m[0] - p[0],
                self.min_m[1] + self.size_m[1] - p[1],
                p[2],
            ]
        } else {
            [self.min_m[0] + p[0], self.min_m[1] + p[1], p[2]]
        }
    }

    /// A world point in the room's frame.
    pub fn room_from_world(&self, p: [f64; 3]) -> [f64; 3] {
        // The 180-degree turn is its own inverse.
        if self.turned {
            self.world_from_room(p)
        } else {
            [p[0] - self.min_m[0], p[1] - self.min_m[1], p[2]]
        }
    }

    /// A room-frame box in the world.
    pub fn world_box(&self, b: &SceneBox) -> SceneBox {
        let c = self.world_from_room([b.center_xy_m[0], b.center_xy_m[1], 0.0]);
        let sign = if self.turned { -1.0 } else { 1.0 };
        SceneBox {
            center_xy_m: [c[0], c[1]],
            yaw_cos_sin: b.yaw_cos_sin.map(|v| sign * v),
            ..*b
        }
    }
}

/// The building's floor plan. See the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorPlan {
    /// What it was generated from.
    pub spec: BuildingSpec,
    /// The room designs.
    pub designs: Vec<RoomDesign>,
    /// The rooms, in the order of their doors along the corridor.
    pub rooms: Vec<PlacedRoom>,
    /// What stands in each room, in [`FloorPlan::rooms`] order.
    pub furnishings: Vec<Furnishing>,
    /// Corridor floor, smallest corner, world.
    pub corridor_min_m: [f64; 2],
    /// Corridor floor, largest corner, world.
    pub corridor_max_m: [f64; 2],
    /// The building's bounding box `[x, y, z]` from the origin, meters.
    pub size_m: [f64; 3],
}

impl FloorPlan {
    /// The plan for `spec` (taken as it is: validate it first) and `seed`.
    pub fn generate(spec: &BuildingSpec, seed: u64) -> Self {
        let root = SplitMix64::new(seed);
        let mut rng = root.fork(11);
        let designs: Vec<RoomDesign> = (0..spec.designs.max(1))
            .map(|d| design(spec, d, &mut rng, root.fork(1000 + d as u64)))
            .collect();
        // Designs dealt in shuffled rounds, so each appears about equally.
        let mut order = Vec::with_capacity(spec.rooms);
        while order.len() < spec.rooms {
            let mut round: Vec<usize> = (0..designs.len()).collect();
            for i in (1..round.len()).rev() {
                round.swap(i, rng.below(i + 1));
            }
            order.extend(round);
        }
        order.truncate(spec.rooms);

        let t = spec.wall_thickness_m;
        let size = |d: usize| designs.get(d).map_or([4.0, 5.0], |x| x.size_m);
        let south: Vec<usize> = order.iter().copied().step_by(2).collect();
        let north: Vec<usize> = order.iter().copied().skip(1).step_by(2).collect();
        let deepest = |row: &[usize]| row.iter().map(|&d| size(d)[1]).fold(0.0, f64::max);
        let row_length = |row: &[usize]| row.iter().map(|&d| size(d)[0] + t).sum::<f64>() - t;
        let corridor_y0 = t + deepest(&south);
        let corridor_y1 = corridor_y0 + spec.corridor_width_m;
        let length = row_length(&south).max(row_length(&north));
        let mut rooms = Vec::with_capacity(spec.rooms);
        for (row, turned) in [(&south, true), (&north, false)] {
            let mut x = 0.0;
            for &d in row.iter() {
                let [w, depth] = size(d);
                let y = if turned {
                    corridor_y0 - t - depth
                } else {
                    corridor_y1 + t
                };
                rooms.push(PlacedRoom {
                    design: d,
                    min_m: [x, y],
                    size_m: [w, depth],
                    turned,
                });
                x += w + t;
            }
        }
        let door_x = |r: &PlacedRoom| {
            let c = designs.get(r.design).map_or(0.0, |d| d.door_center_m);
            r.world_from_room([c, 0.0, 0.0])[0]
        };
        rooms.sort_by(|a, b| door_x(a).total_cmp(&door_x(b)));
        let furnishings = rooms
            .iter()
            .enumerate()
            .map(|(i, r)| match designs.get(r.design) {
                Some(d) if spec.identical_rooms => d.furnishing.clone(),
                Some(d) => furnish_room(spec, r.design, d, root.fork(3000 + i as u64)),
                None => Furnishing::default(),
            })
            .collect();
        let north_depth = deepest(&north);
        Self {
            spec: *spec,
            designs,
            rooms,
            furnishings,
            corridor_min_m: [0.0, corridor_y0],
            corridor_max_m: [length, corridor_y1],
            size_m: [
                length,
                corridor_y1
                    + if north.is_empty() {
                        0.0
                    } else {
                        t + north_depth
                    },
                spec.height_m,
            ],
        }
    }

    /// The floor rectangles `(min, size)` (world, meters) of the rooms, in
    /// [`FloorPlan::rooms`] order, then of the corridor.
    pub fn spaces(&self) -> Vec<([f64; 2], [f64; 2])> {
        let corridor_size = [
            self.corridor_max_m[0] - self.corridor_min_m[0],
            self.corridor_max_m[1] - self.corridor_min_m[1],
        ];
        self.rooms
            .iter()
            .map(|r| (r.min_m, r.size_m))
            .chain(std::iter::once((self.corridor_min_m, corridor_size)))
            .collect()
    }

    /// The number (in [`FloorPlan::spaces`]) of the space whose floor
    /// rectangle holds `p`'s `x` and `y`, or `None` (in a wall or a
    /// doorway's reveal, or outside).
    pub fn space_at(&self, p: [f64; 3]) -> Option<usize> {
        self.spaces()
            .iter()
            .position(|(min, size)| (0..2).all(|k| p[k] >= min[k] && p[k] <= min[k] + size[k]))
    }

    /// Floor area of the rooms and the corridor, m².
    pub fn floor_area_m2(&self) -> f64 {
        let corridor = (self.corridor_max_m[0] - self.corridor_min_m[0])
            * (self.corridor_max_m[1] - self.corridor_min_m[1]);
        corridor
            + self
                .rooms
                .iter()
                .map(|r| r.size_m[0] * r.size_m[1])
                .sum::<f64>()
    }

    /// True when `p_world` is inside a room, the corridor or a doorway by
    /// at least `margin_m` from walls, floor, ceiling and door frames
    /// (furniture is the scene's to check).
    pub fn is_free(&self, p: [f64; 3], margin_m: f64) -> bool {
        let spec = &self.spec;
        if p[2] < margin_m || p[2] > spec.height_m - margin_m {
            return false;
        }
        let in_rect = |min: [f64; 2], max: [f64; 2]| {
            p[0] >= min[0] + margin_m
                && p[0] <= max[0] - margin_m
                && p[1] >= min[1] + margin_m
                && p[1] <= max[1] - margin_m
        };
        if in_rect(self.corridor_min_m, self.corridor_max_m) {
            return true;
        }
        self.rooms.iter().any(|r| {
            let max = [r.min_m[0] + r.size_m[0], r.min_m[1] + r.size_m[1]];
            if in_rect(r.min_m, max) {
                return true;
            }
            let Some(design) = self.designs.get(r.design) else {
                return false;
            };
            // The doorway, from the corridor's free space to the room's.
            let q = r.room_from_world(p);
            let half = 0.5 * spec.door_width_m - margin_m;
            (q[0] - design.door_center_m).abs() <= half
                && q[1] >= -spec.wall_thickness_m - margin_m
                && q[1] <= margin_m
                && q[2] <= spec.door_height_m - margin_m
        })
    }

    /// The tour points of each room, world frame, in [`FloorPlan::rooms`]
    /// order.
    pub fn routes(&self) -> Vec<RoomRoute> {
        let t = self.spec.wall_thickness_m;
        let half_corridor = 0.5 * self.spec.corridor_width_m;
        self.rooms
            .iter()
            .filter_map(|r| {
                let design = self.designs.get(r.design)?;
                let c = design.door_center_m;
                let w = |p: [f64; 2]| {
                    let q = r.world_from_room([p[0], p[1], 0.0]);
                    [q[0], q[1]]
                };
                let [inside, l, b, rr] = design.route_m;
                Some(RoomRoute {
                    corridor_m: w([c, -t - half_corridor]),
                    door_m: w([c, -0.5 * t]),
                    inside_m: w(inside),
                    loop_m: [w(l), w(b), w(rr)],
                })
            })
            .collect()
    }
}

/// Design `index`: size and door drawn from `rng`, furniture from
/// `furniture_rng`.
fn design(
    spec: &BuildingSpec,
    index: usize,
    rng: &mut SplitMix64,
    furniture_rng: SplitMix64,
) -> RoomDesign {
    // Widths cycle so that a few designs already span the sizes.
    let w = WIDTHS_M[(index + rng.below(2)) % WIDTHS_M.len()];
    let d = DEPTHS_M[rng.below(DEPTHS_M.len())];
    let door_center_m = match rng.below(3) {
        0 => 0.5 * w,
        1 => DOOR_FROM_SIDE_M,
        _ => w - DOOR_FROM_SIDE_M,
    };
    let a = (0.5 * w - 1.3).clamp(0.5, 1.2);
    let route_m = [
        [door_center_m, INSIDE_M],
        [0.5 * w - a, 0.5 * d],
        [0.5 * w, d - 1.5],
        [0.5 * w + a, 0.5 * d],
    ];
    let mut design = RoomDesign {
        size_m: [w, d],
        door_center_m,
        texture_set: index % spec.texture_sets.max(1),
        furnishing: Furnishing::default(),
        route_m,
    };
    design.furnishing = furnish_room(spec, index, &design, furniture_rng);
    design
}

/// Furniture (and, in every other design, occluders) for one room of
/// design `index`, kept off the design's tour path, drawn from `rng`.
fn furnish_room(
    spec: &BuildingSpec,
    index: usize,
    design: &RoomDesign,
    mut rng: SplitMix64,
) -> Furnishing {
    let [w, d] = design.size_m;
    let route_m = design.route_m;
    let keep_out = KeepOut {
        polygon: route_m.to_vec(),
        segments: vec![
            [[design.door_center_m, -1.0], route_m[0]],
            [route_m[0], route_m[1]],
            [route_m[1], route_m[2]],
            [route_m[2], route_m[3]],
            [route_m[3], route_m[0]],
        ],
        distance_m: KEEP_OUT_M,
    };
    let furniture = furnish::place(
        &mut rng,
        [w, d],
        &keep_out,
        &[],
        spec.furniture_per_room,
        false,
    );
    // Every other design has occluders (objects the map lacks).
    let occluders = if index % 2 == 1 {
        furnish::place(
            &mut rng,
            [w, d],
            &keep_out,
            &furniture,
            spec.occluders_per_room,
            true,
        )
    } else {
        Vec::new()
    };
    Furnishing {
        furniture,
        occluders,
    }
}
