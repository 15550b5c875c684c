//! The building scene: a floor of many rooms joined by a corridor and
//! doorways, for figures and tests at the scale of a whole building.
//!
//! Takes a [`BuildingSpec`] and a seed; gives out a [`Scene`] like the one
//! room's (a `map` mesh without occluders, a `truth` mesh with them,
//! furniture and occluders as boxes) plus its [`FloorPlan`], which answers
//! the free-space test ([`Scene::is_free`]) and gives the room-to-room
//! tour its points. World frame as the one room's: meters, `z` up, the
//! floor at `z = 0`, the origin at the building's corner (`x` along the
//! corridor).
//!
//! Look-alike places on purpose: every room is one of
//! [`BuildingSpec::designs`] designs (size, door, textures: the same shell
//! to the last vertex), dealt round the floor, and designs share
//! [`BuildingSpec::texture_sets`] texture sets. Each room is furnished on
//! its own from one furniture atlas, so rooms of a design differ only in
//! where their furniture stands; [`BuildingSpec::identical_rooms`] gives
//! every room its design's furniture, and then only the view through the
//! door tells two rooms of a design apart. The surfaces are cut into
//! cells of [`BuildingSpec::cell_m`] (3.7 cm by default: about 5.9 M map
//! triangles for the 22 rooms), denser than the one room's 12.5 cm, to
//! make a map of the size a scanned building gives.
//!
//! - `layout`: the floor plan, designs, free space and tour points;
//! - `furnish`: furniture and occluders kept off the tour's path;
//! - `mesh`: the meshes and textures.

mod furnish;
mod layout;
mod mesh;

use std::sync::Arc;

use serde::Serialize;

pub use layout::{FloorPlan, Furnishing, PlacedRoom, RoomDesign};

use super::{Scene, FREE_MARGIN_M};

/// Most rooms of a building.
pub const MAX_ROOMS: usize = 64;

/// The parameters of a building floor (the seed comes apart).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BuildingSpec {
    /// Rooms, half on each side of the corridor (the odd one south).
    pub rooms: usize,
    /// Floor to ceiling, everywhere, m.
    pub height_m: f64,
    /// Corridor width, m.
    pub corridor_width_m: f64,
    /// Wall thickness between rooms and between a room and the corridor, m.
    pub wall_thickness_m: f64,
    /// Doorway width, m.
    pub door_width_m: f64,
    /// Doorway height, m.
    pub door_height_m: f64,
    /// Distinct room designs the rooms repeat.
    pub designs: usize,
    /// Distinct floor/ceiling/wall texture sets the designs share.
    pub texture_sets: usize,
    /// Furniture boxes tried per room (fewer when they do not fit).
    pub furniture_per_room: usize,
    /// Occluders (truth only) per room, in the rooms of every other design.
    pub occluders_per_room: usize,
    /// Every room of a design gets the design's furniture: rooms of one
    /// design are then the same to the last vertex (twins that only a
    /// motion prior or the view through the door tells apart). Off, each
    /// room is furnished on its own (look-alikes).
    pub identical_rooms: bool,
    /// Edge of the surface cells, m.
    pub cell_m: f64,
    /// Texture resolution, texels per meter.
    pub texture_px_per_m: f64,
}

impl Default for BuildingSpec {
    fn default() -> Self {
        Self {
            rooms: 22,
            height_m: 3.0,
            corridor_width_m: 2.4,
            wall_thickness_m: 0.2,
            door_width_m: 1.6,
            door_height_m: 2.3,
            designs: 6,
            texture_sets: 4,
            furniture_per_room: 6,
            occluders_per_room: 1,
            identical_rooms: false,
            cell_m: 0.037,
            texture_px_per_m: 128.0,
        }
    }
}

/// An invalid [`BuildingSpec`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("building parameter {field} = {value} is invalid: expected {expected}")]
pub struct BuildingSpecError {
    /// The field.
    pub field: &'static str,
    /// The value found.
    pub value: f64,
    /// The accepted range.
    pub expected: &'static str,
}

impl BuildingSpec {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), BuildingSpecError> {
        let checks: [(&'static str, f64, f64, f64, &'static str); 9] = [
            ("rooms", self.rooms as f64, 1.0, MAX_ROOMS as f64, "1..=64"),
            ("height_m", self.height_m, 2.6, 6.0, "2.6..=6 m"),
            (
                "corridor_width_m",
                self.corridor_width_m,
                1.8,
                6.0,
                "1.8..=6 m",
            ),
            (
                "wall_thickness_m",
                self.wall_thickness_m,
                0.05,
                0.5,
                "0.05..=0.5 m",
            ),
            ("door_width_m", self.door_width_m, 1.2, 2.0, "1.2..=2 m"),
            (
                "door_height_m",
                self.door_height_m,
                2.1,
                self.height_m - 0.2,
                "2.1 m..=height_m - 0.2 m",
            ),
            ("designs", self.designs as f64, 1.0, 64.0, "1..=64"),
            (
                "texture_sets",
                self.texture_sets as f64,
                1.0,
                16.0,
                "1..=16",
            ),
            ("cell_m", self.cell_m, 0.02, 0.5, "0.02..=0.5 m"),
        ];
        for (field, value, lo, hi, expected) in checks {
            if !(lo..=hi).contains(&value) {
                return Err(BuildingSpecError {
                    field,
                    value,
                    expected,
                });
            }
        }
        if !(8.0..=1024.0).contains(&self.texture_px_per_m) {
            return Err(BuildingSpecError {
                field: "texture_px_per_m",
                value: self.texture_px_per_m,
                expected: "8..=1024",
            });
        }
        Ok(())
    }
}

/// The building for `spec` and `seed` as a [`Scene`]: deterministic in
/// both, bit for bit. `spec` must be valid ([`BuildingSpec::validate`]).
pub fn build_building(spec: &BuildingSpec, seed: u64) -> Scene {
    let plan = FloorPlan::generate(spec, seed);
    let (map, truth) = mesh::build_meshes(&plan, seed);
    let mut furniture = Vec::new();
    let mut occluders = Vec::new();
    for (room, f) in plan.rooms.iter().zip(&plan.furnishings) {
        furniture.extend(f.furniture.iter().map(|b| room.world_box(b)));
        occluders.extend(f.occluders.iter().map(|b| room.world_box(b)));
    }
    let size = plan.size_m;
    Scene {
        map,
        truth,
        free_min_m: [FREE_MARGIN_M; 3],
        free_max_m: [
            size[0] - FREE_MARGIN_M,
            size[1] - FREE_MARGIN_M,
            size[2] - FREE_MARGIN_M,
        ],
        room_size_m: size,
        furniture,
        occluders,
        plan: Some(Arc::new(plan)),
    }
}

#[cfg(test)]
mod tests;
