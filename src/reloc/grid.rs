//! Where the relocalization database's views are (`star reloc build`):
//! virtual cameras on a grid in the map's free space, and along a
//! trajectory. [`super::build`] renders and describes them.
//!
//! Takes the map mesh and the `[reloc]` section; gives out the poses to
//! render. Positions lie on a horizontal grid inside
//! the mesh bounds (shrunk by `bounds_margin_m`) at the configured heights
//! above the floor (`floor_z_m`, or the floor found in the map);
//! each position gets `yaw_steps` yaws times the configured pitches. A
//! position is dropped when any of its views has geometry nearer than
//! `min_depth_m` (inside or against furniture); a view is dropped when less
//! than `min_valid_fraction` of it sees the map (outside, or facing a hole).
//! Views are rendered at twice the thumbnail size, which is all the
//! descriptor needs and keeps the build fast. Landmarks come from a second,
//! sparser grid (`landmark_spacing_m`, `landmark_heights_m`,
//! `landmark_yaw_steps`) of full-resolution views.
//!
//! A trajectory (`star reloc build --poses`: the scanning run, an earlier
//! flight) adds views where the vehicle will fly, at the heights, pitches
//! and rolls it flew with, which the grid does not sample: poses taken
//! along it every [`AlongTrajectory::spacing_m`] (or turn of half a grid
//! yaw step), each also turned half a yaw step either way and moved half a
//! spacing to either side ([`trajectory_views`]), and full-resolution
//! landmark views every `landmark_spacing_m` along it.

use nalgebra::{Translation3, Vector3};

use crate::geometry::look::camera_rotation;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::floor::{find_floor, FloorError};
use crate::map::Mesh;
use crate::render::RenderError;

use super::config::RelocConfig;
use super::descriptor::{THUMB_H, THUMB_W};

/// Errors building a database.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// The mesh has no vertices.
    #[error("the map mesh is empty")]
    EmptyMap,
    /// The grid has no position inside the mesh bounds.
    #[error("no grid position fits inside the map bounds {min:?}..{max:?} with margin {margin_m} m at heights {heights_m:?}")]
    NoPositions {
        /// Lower bound of the mesh, meters.
        min: [f32; 3],
        /// Upper bound of the mesh, meters.
        max: [f32; 3],
        /// The margin.
        margin_m: f64,
        /// The heights asked for.
        heights_m: Vec<f64>,
    },
    /// No floor was found to measure the heights from.
    #[error("the grid heights are measured from the floor, and {source}; set `[reloc] floor_z_m` to the floor's height (world z, meters) to give it explicitly")]
    NoFloor {
        /// Why none was found.
        #[source]
        source: FloorError,
    },
    /// A build worker's renderer did not start.
    #[error("starting a renderer for the database build")]
    RendererStart(#[source] RenderError),
    /// The checkpoint next to the output could not be read or written.
    #[error("database build checkpoint {path}: {source}")]
    Checkpoint {
        /// The checkpoint file.
        path: std::path::PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The build stopped after the work units asked for
    /// ([`super::build::BuildOptions::stop_after`]); the checkpoint holds them.
    #[error("database build stopped after {done} of {total} work units (checkpoint kept)")]
    Stopped {
        /// Work units done.
        done: usize,
        /// Work units in all.
        total: usize,
    },
    /// A render failed.
    #[error("rendering a database view at {position_m:?}")]
    Render {
        /// Where the camera was.
        position_m: [f64; 3],
        /// The renderer's error.
        #[source]
        source: RenderError,
    },
}

/// The camera the database views are rendered with: `camera` (pinhole part)
/// scaled to twice the thumbnail size, pixel centers at integers.
pub fn thumb_render_camera(camera: &PinholeCamera) -> PinholeCamera {
    let (w, h) = (2 * THUMB_W as u32, 2 * THUMB_H as u32);
    let sx = w as f64 / camera.width.max(1) as f64;
    let sy = h as f64 / camera.height.max(1) as f64;
    PinholeCamera::new(
        w,
        h,
        camera.fx * sx,
        camera.fy * sy,
        (camera.cx + 0.5) * sx - 0.5,
        (camera.cy + 0.5) * sy - 0.5,
    )
}

/// Grid positions (world, meters) inside the bounds of `mesh`, or inside
/// `region` (`[min, max]` corners, meters) when given, at `heights_m` taken
/// as world heights (see [`above_floor`]).
pub fn grid_positions(
    mesh: &Mesh,
    config: &RelocConfig,
    region: Option<([f32; 3], [f32; 3])>,
) -> Result<Vec<Vector3<f64>>, BuildError> {
    let (min, max) = match region {
        Some(r) => r,
        None => mesh.bounds().ok_or(BuildError::EmptyMap)?,
    };
    let m = config.bounds_margin_m;
    let lo = Vector3::new(min[0] as f64 + m, min[1] as f64 + m, min[2] as f64 + m);
    let hi = Vector3::new(max[0] as f64 - m, max[1] as f64 - m, max[2] as f64 - m);
    let step = config.grid_spacing_m;
    let axis = |lo: f64, hi: f64| -> Vec<f64> {
        if hi < lo {
            return Vec::new();
        }
        // Center the grid in the span.
        let n = ((hi - lo) / step).floor() as usize + 1;
        let start = lo + 0.5 * ((hi - lo) - (n - 1) as f64 * step);
        (0..n).map(|i| start + i as f64 * step).collect()
    };
    let (xs, ys) = (axis(lo.x, hi.x), axis(lo.y, hi.y));
    let mut out = Vec::new();
    for &z in config.heights_m.iter().filter(|&&z| z >= lo.z && z <= hi.z) {
        for &y in &ys {
            for &x in &xs {
                out.push(Vector3::new(x, y, z));
            }
        }
    }
    if out.is_empty() {
        return Err(BuildError::NoPositions {
            min,
            max,
            margin_m: m,
            heights_m: config.heights_m.clone(),
        });
    }
    Ok(out)
}

/// Views per grid position.
pub fn views_per_position(config: &RelocConfig) -> usize {
    config.yaw_steps as usize * config.pitches_deg.len()
}

/// Views along a trajectory to add to a database build.
#[derive(Debug, Clone, Default)]
pub struct AlongTrajectory {
    /// `world_from_camera` poses of the trajectory, in time order.
    pub poses: Vec<Pose>,
    /// Distance between sampled poses, meters.
    pub spacing_m: f64,
}

/// The poses sampled along `poses`: the first, then each one at least
/// `spacing_m` from, or turned at least `turn_rad` from, the last one taken.
pub fn sample_along(poses: &[Pose], spacing_m: f64, turn_rad: f64) -> Vec<Pose> {
    let mut out: Vec<Pose> = Vec::new();
    for p in poses {
        let take = out.last().is_none_or(|last| {
            (p.translation.vector - last.translation.vector).norm() >= spacing_m
                || last.rotation.angle_to(&p.rotation) >= turn_rad
        });
        if take {
            out.push(*p);
        }
    }
    out
}

/// The database views of one sampled trajectory pose: the pose itself,
/// turned `half_yaw_rad` either way about the world vertical, and moved
/// `half_spacing_m` either way along its horizontal right axis (the
/// vehicle's path is not flown twice the same).
pub fn trajectory_views(pose: &Pose, half_yaw_rad: f64, half_spacing_m: f64) -> [Pose; 5] {
    let turned = |yaw: f64| {
        Pose::from_parts(
            pose.translation,
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw) * pose.rotation,
        )
    };
    let right = pose.rotation * Vector3::x();
    let right_level = Vector3::new(right.x, right.y, 0.0)
        .try_normalize(1e-9)
        .unwrap_or_else(Vector3::x);
    let moved = |d: f64| {
        Pose::from_parts(
            Translation3::from(pose.translation.vector + right_level * d),
            pose.rotation,
        )
    };
    [
        *pose,
        turned(half_yaw_rad),
        turned(-half_yaw_rad),
        moved(half_spacing_m),
        moved(-half_spacing_m),
    ]
}

/// `config` with its heights made world heights: the floor's height (the
/// configured `floor_z_m`, else [`find_floor`]) added, and `floor_z_m`
/// set to 0.
pub fn above_floor(mesh: &Mesh, config: &RelocConfig) -> Result<RelocConfig, BuildError> {
    let floor_z_m = match config.floor_z_m {
        Some(z) => z,
        None => {
            let floor = find_floor(mesh).map_err(|source| BuildError::NoFloor { source })?;
            tracing::info!(
                floor_z_m = floor.z_m,
                area_m2 = floor.area_m2,
                "relocalization grid: heights measured from the floor found in the map"
            );
            floor.z_m
        }
    };
    let lift = |h: &[f64]| h.iter().map(|z| z + floor_z_m).collect();
    Ok(RelocConfig {
        heights_m: lift(&config.heights_m),
        landmark_heights_m: lift(&config.landmark_heights_m),
        floor_z_m: Some(0.0),
        ..config.clone()
    })
}

/// Positions of the landmark views (none when `landmark_spacing_m` is 0 or
/// no landmark height fits in the bounds).
pub(super) fn landmark_positions(
    mesh: &Mesh,
    config: &RelocConfig,
    region: Option<([f32; 3], [f32; 3])>,
) -> Vec<Vector3<f64>> {
    if config.landmark_spacing_m <= 0.0 {
        return Vec::new();
    }
    let grid = RelocConfig {
        grid_spacing_m: config.landmark_spacing_m,
        heights_m: config.landmark_heights_m.clone(),
        ..config.clone()
    };
    grid_positions(mesh, &grid, region).unwrap_or_else(|e| {
        tracing::warn!(error = %e, "no landmark views: the database will have no landmarks");
        Vec::new()
    })
}

/// The landmark views of the grid: `landmark_yaw_steps` yaws at the mean
/// pitch, per position.
pub(super) fn landmark_grid_poses(config: &RelocConfig, positions: &[Vector3<f64>]) -> Vec<Pose> {
    let pitches = &config.pitches_deg;
    let pitch_rad = (pitches.iter().sum::<f64>() / pitches.len().max(1) as f64).to_radians();
    positions
        .iter()
        .flat_map(|p| {
            config.landmark_yaws_rad().map(move |yaw_rad| {
                Pose::from_parts(
                    Translation3::from(*p),
                    camera_rotation(yaw_rad, pitch_rad, 0.0),
                )
            })
        })
        .collect()
}
