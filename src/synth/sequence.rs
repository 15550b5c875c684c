//! A synthetic sequence written as a TUM-layout dataset folder: what
//! `star synth --preset NAME OUT` does.
//!
//! Takes a [`Preset`], a seed and a frame count; builds the scene, writes
//! the map mesh (with holes) to `map/map.obj`, generates the trajectory,
//! and for every frame renders the image mesh (map or truth, per preset)
//! through the CPU rasterizer: sub-frames across the exposure for motion
//! blur, an enlarged pinhole render resampled through the lens distortion,
//! then gain/bias drift, vignetting and noise. Writes `rgb/`, `depth/`
//! (ideal depth of the image mesh at the frame time, 16-bit), `rgb.txt`,
//! `depth.txt`, `groundtruth.txt`, `camera.toml` and `synth.toml` (the
//! exact preset and seed). Same preset, seed and count: same bytes.
//!
//! With a scanned preset ([`Preset::scanned`]) the map is instead rebuilt
//! by [`super::scanned::build_scanned_map`] (a scanning run fused by
//! Open3D, stored in the scanner's frame), `star.toml` declares its
//! placement (`[map.world_from_mesh]`), `scan_groundtruth.txt` holds the
//! scanning walk, and each flight sub-frame is shaded by a moving light
//! before blur, distortion and the sensor model, with an auto-exposure
//! gain applied before the sensor model.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::Vector3;

use super::camera_model::{SyntheticCamera, SyntheticCameraError};
use super::corrupt::derive_seed;
use super::preset::{ImageSource, Preset};
use super::scanned::exposure::ExposureSchedule;
use super::scanned::fusion::FusionStats;
use super::scanned::lighting::{depth_normals, shade};
use super::scanned::{
    build_scanned_map, flight_light_box, star_toml_text, ScanTools, ScannedError,
};
use super::scene::{build_scene, Scene, SceneParams};
use super::trajectory::{RoomBox, SynthTrajectory, TrajectoryError, TrajectoryKind};
use crate::dataset::{CameraFile, DatasetError, DatasetWriter, Trajectory};
use crate::imgproc::{ImageF32, ImageU8};
use crate::map::MapError;
use crate::render::RenderError;

/// First TUM timestamp of a synthetic sequence, seconds (any positive
/// value works; a realistic one catches tools that assume small stamps).
pub const START_STAMP_S: f64 = 1_000.0;
/// Most frames one sequence may have (10 minutes at 50 Hz).
pub const MAX_FRAMES: usize = 30_000;

/// What to write.
#[derive(Debug, Clone)]
pub struct SequenceOptions {
    /// The preset.
    pub preset: Preset,
    /// Seed of scene, trajectory and noise.
    pub seed: u64,
    /// Number of frames (at the preset's rate).
    pub frames: usize,
    /// Also write depth images.
    pub write_depth: bool,
}

/// Why a sequence could not be written.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// The frame count is zero or above [`MAX_FRAMES`].
    #[error("frame count {found} is out of range: expected 1..={MAX_FRAMES}")]
    FrameCount {
        /// The count asked for.
        found: usize,
    },
    /// No collision-free trajectory in the scene.
    #[error("cannot place the trajectory")]
    Trajectory(#[from] TrajectoryError),
    /// The synthetic camera (lens distortion warp, renderer) cannot be built.
    #[error("cannot build the synthetic camera")]
    Camera(#[from] SyntheticCameraError),
    /// Rendering failed.
    #[error("rendering failed")]
    Render(#[from] RenderError),
    /// Writing the map mesh failed.
    #[error("writing the map mesh")]
    Map(#[from] MapError),
    /// Writing the dataset failed.
    #[error("writing the dataset")]
    Dataset(#[from] DatasetError),
    /// Building the scanned map failed.
    #[error("building the scanned map")]
    Scanned(#[from] ScannedError),
    /// The building parameters are out of range.
    #[error("invalid building")]
    Building(#[from] super::scene::building::BuildingSpecError),
    /// Writing `synth.toml` failed.
    #[error("writing {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// What was written.
#[derive(Debug, Clone)]
pub struct SequenceSummary {
    /// The dataset folder.
    pub root: PathBuf,
    /// The map mesh (`map/map.obj`).
    pub map_path: PathBuf,
    /// Frames written.
    pub frames: usize,
    /// Triangles in the map mesh.
    pub map_triangles: usize,
    /// Total renders (sub-frames included).
    pub renders: usize,
    /// What the scanned variant built; `None` for a closed-world preset.
    pub scanned: Option<ScannedSummary>,
    /// The building's rooms, floor area (m²) and footprint `[x, y]` (m);
    /// `None` for the one room.
    pub building: Option<(usize, f64, [f64; 2])>,
}

/// What the scanned variant built.
#[derive(Debug, Clone)]
pub struct ScannedSummary {
    /// `star.toml`: the config that places the map in the world.
    pub config_path: PathBuf,
    /// Scan frames fused.
    pub scan_frames: usize,
    /// Vertices of the fused map.
    pub map_vertices: usize,
    /// Time rendering the scanning run, seconds.
    pub scan_render_s: f64,
    /// The fusion's statistics (time, peak memory, tiles).
    pub fusion: FusionStats,
}

/// The scene of `preset` for `seed`: the building when the preset has one
/// (its spec must be valid; a building has its look-alikes built in and
/// ignores `texture_seed`), else the one room.
pub fn preset_scene(preset: &Preset, seed: u64) -> Scene {
    if let Some(spec) = &preset.scene.building {
        return super::scene::building::build_building(spec, seed);
    }
    build_scene(&SceneParams {
        seed,
        texture_seed: preset.scene.texture_seed,
        room_size_m: preset.scene.room_size_m,
        boxes: preset.scene.furniture_boxes,
        texture_px_per_m: preset.scene.texture_px_per_m,
        hole_fraction: preset.scene.map_hole_fraction,
        occluders: preset.scene.occluders,
    })
}

/// The trajectory of `preset` in `scene` for `seed`, collision-free for
/// at least `duration_s`.
pub fn preset_trajectory(
    preset: &Preset,
    scene: &Scene,
    seed: u64,
    duration_s: f64,
) -> Result<SynthTrajectory, TrajectoryError> {
    let is_free = |p: &Vector3<f64>, clearance_m| scene.is_free([p.x, p.y, p.z], clearance_m);
    if preset.trajectory == TrajectoryKind::RoomToRoom {
        let Some(plan) = &scene.plan else {
            return Err(TrajectoryError::NoRooms);
        };
        return SynthTrajectory::generate_tour(&plan.routes(), seed, duration_s, &is_free);
    }
    let room = RoomBox {
        min_m: Vector3::zeros(),
        max_m: Vector3::from(scene.room_size_m),
    };
    SynthTrajectory::generate(preset.trajectory, &room, seed, duration_s, &is_free)
}

/// Most scene layouts tried by [`scene_with_trajectory`].
pub const MAX_SCENE_ATTEMPTS: u64 = 16;

/// The scene and trajectory of `preset` for `seed`. When furniture blocks
/// every loop the trajectory generator tries (or, for a scanned preset,
/// every scanning walk), the furniture layout is drawn again from seeds
/// derived from `seed` (deterministically), up to [`MAX_SCENE_ATTEMPTS`]
/// layouts. Returns the scene seed actually used.
pub fn scene_with_trajectory(
    preset: &Preset,
    seed: u64,
    duration_s: f64,
) -> Result<(Scene, SynthTrajectory, u64), TrajectoryError> {
    let mut attempt = 0;
    loop {
        let scene_seed = if attempt == 0 {
            seed
        } else {
            super::corrupt::derive_seed(seed, 0x5ce0_0000 + attempt)
        };
        let scene = preset_scene(preset, scene_seed);
        let scan_blocked = preset
            .scanned
            .as_ref()
            .and_then(|spec| super::scanned::scan_path_for(&scene, spec, seed).err());
        match preset_trajectory(preset, &scene, seed, duration_s) {
            Ok(trajectory) if scan_blocked.is_none() => return Ok((scene, trajectory, scene_seed)),
            // The scanning walk is blocked but the flight is not: the
            // flight's error is all the caller can be told after the last
            // layout.
            Ok(trajectory) if attempt + 1 >= MAX_SCENE_ATTEMPTS => {
                tracing::warn!(seed, scene_seed, error = ?scan_blocked, "no layout fits the scanning walk");
                return Ok((scene, trajectory, scene_seed));
            }
            Ok(_) => {
                tracing::debug!(seed, scene_seed, error = ?scan_blocked, "layout blocks the scanning walk; drawing another")
            }
            Err(e) if attempt + 1 >= MAX_SCENE_ATTEMPTS => return Err(e),
            Err(e) => {
                tracing::debug!(seed, scene_seed, error = %e, "layout blocks the trajectory; drawing another")
            }
        }
        attempt += 1;
    }
}

/// Writes the sequence into `out`; `progress` is called after each frame
/// with the number of frames done. A scanned preset finds Python through
/// [`ScanTools::from_env`].
pub fn write_sequence(
    out: &Path,
    options: &SequenceOptions,
    progress: &mut dyn FnMut(usize),
) -> Result<SequenceSummary, SequenceError> {
    write_sequence_with(
        out,
        options,
        &ScanTools::from_env(),
        &mut |_, _| {},
        progress,
    )
}

/// [`write_sequence`] with the scanned variant's tools given, and
/// `scan_progress(done, total)` called per scan frame rendered.
pub fn write_sequence_with(
    out: &Path,
    options: &SequenceOptions,
    tools: &ScanTools,
    scan_progress: &mut dyn FnMut(usize, usize),
    progress: &mut dyn FnMut(usize),
) -> Result<SequenceSummary, SequenceError> {
    let preset = &options.preset;
    if options.frames == 0 || options.frames > MAX_FRAMES {
        return Err(SequenceError::FrameCount {
            found: options.frames,
        });
    }
    if let Some(spec) = &preset.scene.building {
        spec.validate()?;
    }
    let duration_s = options.frames as f64 / preset.rate_hz;
    let (scene, trajectory, scene_seed) = scene_with_trajectory(preset, options.seed, duration_s)?;

    let writer = DatasetWriter::create(
        out,
        CameraFile {
            camera: preset.camera,
            depth_scale: preset.depth_scale,
        },
    )?;
    let (map_path, map_triangles, scanned) = match &preset.scanned {
        None => (
            crate::map::write_obj(&scene.map, &writer.map_dir(), "map")?,
            scene.map.triangle_count(),
            None,
        ),
        Some(spec) => {
            let work_dir = out.join("scan_work");
            let map = build_scanned_map(
                &scene,
                spec,
                options.seed,
                &writer.map_dir(),
                &work_dir,
                tools,
                scan_progress,
            )?;
            // The scan's raw frames are large and only the fusion needs them
            // (STAR_SYNTH_KEEP_SCAN=1 keeps them, to rerun the fusion script).
            if std::env::var_os("STAR_SYNTH_KEEP_SCAN").is_none() {
                std::fs::remove_dir_all(&work_dir).map_err(|source| SequenceError::Io {
                    path: work_dir.clone(),
                    source,
                })?;
            }
            let scan_gt = out.join("scan_groundtruth.txt");
            let mut walk = Trajectory::default();
            for i in 0..map.scan_frames {
                let t_s = map.scan_path.duration_s() * i as f64 / map.scan_frames as f64;
                walk.push(START_STAMP_S + t_s, map.scan_path.pose_at(t_s));
            }
            walk.write(&scan_gt)?;
            let abs_obj =
                std::fs::canonicalize(&map.obj_path).map_err(|source| SequenceError::Io {
                    path: map.obj_path.clone(),
                    source,
                })?;
            let config_path = out.join("star.toml");
            std::fs::write(
                &config_path,
                star_toml_text(&abs_obj, &map.world_from_mesh_declared),
            )
            .map_err(|source| SequenceError::Io {
                path: config_path.clone(),
                source,
            })?;
            let summary = ScannedSummary {
                config_path,
                scan_frames: map.scan_frames,
                map_vertices: map.mesh.positions.len(),
                scan_render_s: map.scan_render_s,
                fusion: map.fusion.clone(),
            };
            (
                map.obj_path.clone(),
                map.mesh.triangle_count(),
                Some((summary, map)),
            )
        }
    };
    let synth_toml = out.join("synth.toml");
    let mut text = format!(
        "# The exact parameters this dataset was synthesized with.\nseed = {}\n\
         # Seed of the room layout (the seed, or one derived from it when furniture blocked the trajectory).\n\
         scene_seed = {scene_seed}\nframes = {}\n\n{}",
        options.seed,
        options.frames,
        preset.to_toml()
    );
    if let Some((_, map)) = &scanned {
        let pose_text = |p: &crate::geometry::Pose| {
            let t = p.translation.vector;
            let q = p.rotation.quaternion();
            format!("{} {} {} {} {} {} {}", t.x, t.y, t.z, q.i, q.j, q.k, q.w)
        };
        let mut lights: Vec<[f64; 3]> = Vec::new();
        for l in &map.scan_lights {
            let p = [l.position_m.x, l.position_m.y, l.position_m.z];
            if lights.last() != Some(&p) {
                lights.push(p);
            }
        }
        let light = if lights.len() == 1 {
            format!("{:?}", lights[0])
        } else {
            format!("{lights:?} (one per space)")
        };
        text.push_str(&format!(
            "\n# What the scanned variant drew (poses \"tx ty tz qx qy qz qw\"):\n\
             # the map's declared placement (star.toml, the first scan camera): {}\n\
             # the map's true placement (with the registration error):         {}\n\
             # scan light at {} m; {} scan frames fused into {} tiles\n",
            pose_text(&map.world_from_mesh_declared),
            pose_text(&map.world_from_mesh_true),
            light,
            map.scan_frames,
            map.fusion.tiles,
        ));
    }
    std::fs::write(&synth_toml, text).map_err(|source| SequenceError::Io {
        path: synth_toml.clone(),
        source,
    })?;

    let image_mesh = match preset.images_from {
        ImageSource::Map => scene.map.clone(),
        ImageSource::Truth => scene.truth.clone(),
    };
    // The flight's light and auto-exposure (scanned variant only).
    let flight = preset.scanned.as_ref().map(|spec| {
        let phase_rad = std::f64::consts::TAU * (derive_seed(options.seed, 0xf11) >> 11) as f64
            / (1u64 << 53) as f64;
        let exposure =
            ExposureSchedule::new(&spec.exposure, derive_seed(options.seed, 0xe40), duration_s);
        (spec.flight_light, phase_rad, exposure)
    });
    let mut normals = Vec::new();
    let mut camera = SyntheticCamera::new(
        Arc::new(image_mesh),
        &preset.camera,
        preset.photometric,
        preset.blur,
        options.seed,
    )?;
    let render_camera = *camera.render_camera();
    let mut warped_depth = ImageF32::new(0, 0, 0.0);
    let mut frame = ImageU8::new(0, 0, 0);
    let mut ground_truth = Trajectory::default();
    let (mut rgb, mut depth) = (Vec::new(), Vec::new());
    let mut renders = 0;

    for i in 0..options.frames {
        let t_s = i as f64 / preset.rate_hz;
        let stamp_s = START_STAMP_S + t_s;
        let world_from_camera = trajectory.pose_at(t_s);
        ground_truth.push(stamp_s, world_from_camera);

        // Sub-frames are averaged; the one at the frame time (offset 0 when
        // there is one sub-frame) also gives the depth.
        renders += camera.expose(
            |t| trajectory.pose_at(t),
            t_s,
            |view, pose, t| {
                if let Some((light, phase_rad, _)) = &flight {
                    depth_normals(&view.depth_m, &render_camera, &mut normals);
                    let p = pose.translation.vector;
                    let (origin_m, box_m) = flight_light_box(&scene, [p.x, p.y, p.z]);
                    let mut light = light.at(box_m, *phase_rad, t);
                    light.position_m.x += origin_m[0];
                    light.position_m.y += origin_m[1];
                    shade(
                        &mut view.gray,
                        &view.depth_m,
                        &normals,
                        &render_camera,
                        pose,
                        &light,
                    );
                }
            },
        )?;
        let gain = flight
            .as_ref()
            .map(|(_, _, exposure)| exposure.gain_at(t_s) as f32);
        camera.develop(gain, i as u64, t_s, &mut frame);
        rgb.push(writer.write_rgb(stamp_s, &frame)?);

        if options.write_depth {
            renders += camera.depth(&world_from_camera, true, &mut warped_depth)?;
            depth.push(writer.write_depth_m(stamp_s, &warped_depth)?);
        }
        progress(i + 1);
    }
    writer.finish(&rgb, &depth, Some(&ground_truth))?;
    Ok(SequenceSummary {
        root: out.to_path_buf(),
        map_path,
        frames: options.frames,
        map_triangles,
        renders,
        scanned: scanned.map(|(summary, _)| summary),
        building: scene
            .plan
            .as_ref()
            .map(|p| (p.rooms.len(), p.floor_area_m2(), [p.size_m[0], p.size_m[1]])),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::Dataset;

    fn options(name: &str, frames: usize) -> SequenceOptions {
        SequenceOptions {
            preset: Preset::by_name(name).expect("preset"),
            seed: 3,
            frames,
            write_depth: true,
        }
    }

    #[test]
    fn ideal_sequence_round_trips_through_the_dataset_reader() {
        let tmp = tempfile::tempdir().expect("tmp");
        let mut done = 0;
        let summary =
            write_sequence(tmp.path(), &options("ideal", 3), &mut |n| done = n).expect("write");
        assert_eq!((summary.frames, done), (3, 3));
        let ds = Dataset::open(tmp.path()).expect("open");
        assert_eq!(ds.len(), 3);
        assert_eq!(ds.depth_frames.len(), 3);
        let gt = ds.ground_truth.as_ref().expect("ground truth");
        assert_eq!(gt.len(), 3);
        let frame = ds.load_frame(0).expect("frame");
        assert_eq!((frame.width(), frame.height()), (640, 512));
        // A textured room: many gray levels, little black.
        let mut seen = [false; 256];
        frame.data().iter().for_each(|&v| seen[v as usize] = true);
        assert!(seen.iter().filter(|&&s| s).count() > 64);
        let map = crate::map::load_obj(&summary.map_path).expect("map loads");
        assert_eq!(map.triangle_count(), summary.map_triangles);
    }

    #[test]
    fn same_seed_same_bytes() {
        let a = tempfile::tempdir().expect("tmp");
        let b = tempfile::tempdir().expect("tmp");
        write_sequence(a.path(), &options("realistic", 2), &mut |_| {}).expect("a");
        write_sequence(b.path(), &options("realistic", 2), &mut |_| {}).expect("b");
        let ds = Dataset::open(a.path()).expect("open");
        for entry in &ds.frames {
            let x = std::fs::read(a.path().join(&entry.path)).expect("a png");
            let y = std::fs::read(b.path().join(&entry.path)).expect("b png");
            assert!(x == y, "{} differs", entry.path.display());
        }
    }

    #[test]
    fn blocked_layouts_are_redrawn() {
        // Seeds whose first layout blocks every loop.
        for (name, seeds) in [("realistic", [2, 5]), ("aggressive", [4, 7])] {
            let preset = Preset::by_name(name).expect("preset");
            for seed in seeds {
                let (scene, trajectory, _) =
                    scene_with_trajectory(&preset, seed, 10.0).expect("placed");
                for i in 0..100 {
                    let p = trajectory.position_at(i as f64 * 0.1);
                    assert!(scene.is_free([p.x, p.y, p.z], 0.25), "{name} seed {seed}");
                }
            }
        }
    }

    #[test]
    fn scanned_layouts_fit_the_scanning_walk() {
        let preset = Preset::by_name("scanned").expect("preset");
        let spec = preset.scanned.clone().expect("scanned");
        for seed in 1..=12 {
            let (scene, _, _) = scene_with_trajectory(&preset, seed, 10.0).expect("placed");
            let walk = crate::synth::scanned::scan_path_for(&scene, &spec, seed)
                .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            for i in 0..400 {
                let p = walk.position_at(walk.duration_s() * i as f64 / 400.0);
                assert!(
                    !scene
                        .furniture
                        .iter()
                        .any(|b| b.contains([p.x, p.y, p.z], 0.25)),
                    "seed {seed}"
                );
            }
        }
    }

    /// The building preset at a coarse tessellation (fast to build).
    fn small_building(rooms: usize) -> Preset {
        let mut preset = Preset::by_name("building").expect("preset");
        if let Some(spec) = preset.scene.building.as_mut() {
            spec.rooms = rooms;
            spec.cell_m = 0.25;
            spec.texture_px_per_m = 32.0;
        }
        preset
    }

    #[test]
    fn building_tours_go_room_to_room_in_free_space() {
        for seed in [1, 2, 3] {
            let preset = small_building(6);
            let (scene, trajectory, _) =
                scene_with_trajectory(&preset, seed, 60.0).expect("placed");
            let plan = scene.plan.as_ref().expect("a building");
            let visited = trajectory.rooms_visited();
            assert!(visited.len() >= 3, "seed {seed}: {visited:?}");
            assert!(visited.windows(2).all(|w| w[0] != w[1]));
            // Every 10 ms of the first minute is clear of walls, doors and
            // boxes, and the camera is in the corridor at some times and in
            // rooms at others.
            let (mut in_corridor, mut in_room) = (0, 0);
            for i in 0..6000 {
                let t = i as f64 * 0.01;
                let p = trajectory.position_at(t);
                assert!(
                    scene.is_free([p.x, p.y, p.z], 0.25),
                    "seed {seed}, t {t} s: {p:?}"
                );
                if p.y > plan.corridor_min_m[1] && p.y < plan.corridor_max_m[1] {
                    in_corridor += 1;
                } else {
                    in_room += 1;
                }
                // Looking roughly along the direction of travel.
                let ahead = trajectory.position_at(t + 0.2) - p;
                if ahead.xy().norm() > 0.05 {
                    let (yaw, _, _) = trajectory.yaw_pitch_roll_at(t);
                    let heading = ahead.y.atan2(ahead.x);
                    let off = (yaw - heading + std::f64::consts::PI)
                        .rem_euclid(std::f64::consts::TAU)
                        - std::f64::consts::PI;
                    assert!(
                        off.abs() < 50f64.to_radians(),
                        "seed {seed}, t {t} s: {off}"
                    );
                }
            }
            assert!(
                in_corridor > 200 && in_room > 200,
                "{in_corridor} / {in_room}"
            );
        }
    }

    #[test]
    fn building_sequences_are_the_same_bytes() {
        let run = |dir: &Path| {
            let options = SequenceOptions {
                preset: small_building(2),
                seed: 5,
                frames: 2,
                write_depth: true,
            };
            write_sequence(dir, &options, &mut |_| {}).expect("written")
        };
        let (a, b) = (
            tempfile::tempdir().expect("tmp"),
            tempfile::tempdir().expect("tmp"),
        );
        let summary = run(a.path());
        run(b.path());
        assert_eq!(summary.building.map(|(rooms, _, _)| rooms), Some(2));
        let ds = Dataset::open(a.path()).expect("open");
        for entry in ds.frames.iter().chain(&ds.depth_frames) {
            let x = std::fs::read(a.path().join(&entry.path)).expect("a");
            let y = std::fs::read(b.path().join(&entry.path)).expect("b");
            assert!(x == y, "{} differs", entry.path.display());
        }
        for file in ["map/map.obj", "groundtruth.txt", "synth.toml"] {
            let x = std::fs::read(a.path().join(file)).expect("a");
            assert!(
                x == std::fs::read(b.path().join(file)).expect("b"),
                "{file} differs"
            );
        }
    }

    #[test]
    fn a_building_is_scanned_space_by_space_each_under_its_own_light() {
        let preset = small_building(4).scanned();
        let spec = preset.scanned.clone().expect("scanned");
        assert_eq!(spec.voxel_m, crate::synth::preset::BUILDING_SCAN_VOXEL_M);
        let (scene, _, _) = scene_with_trajectory(&preset, 2, 10.0).expect("placed");
        let plan = scene.plan.clone().expect("building");
        let walk = crate::synth::scanned::scan_path_for(&scene, &spec, 2).expect("walk");
        let spaces = plan.spaces();
        assert_eq!(spaces.len(), 5, "4 rooms and the corridor");
        assert_eq!(walk.lap_count(), spaces.len() * spec.scan_path.laps.len());
        let lights = crate::synth::scanned::scan_lights(&scene, &spec, 2, &walk);
        assert_eq!(lights.len(), walk.lap_count());
        let mut visited = vec![0usize; spaces.len()];
        let n = 4000;
        for i in 0..n {
            let t = walk.duration_s() * i as f64 / n as f64;
            let p = walk.position_at(t);
            let p = [p.x, p.y, p.z];
            assert!(
                !scene.furniture.iter().any(|b| b.contains(p, 0.25)),
                "{p:?} in furniture"
            );
            assert!(plan.is_free(p, 0.25), "{p:?} outside the free space");
            let space = plan.space_at(p).expect("in a room or the corridor");
            // The lap's space is the one the walker stands in, and its
            // light hangs there.
            let lap = walk.lap_index_at(t);
            assert_eq!(lap / spec.scan_path.laps.len(), space, "{p:?}");
            let light = lights[lap].position_m;
            let (min, size) = spaces[space];
            assert!((0..2).all(|k| {
                let l = [light.x, light.y][k];
                l >= min[k] && l <= min[k] + size[k]
            }));
            visited[space] += 1;
        }
        assert!(visited.iter().all(|&v| v > 0), "{visited:?}");
        // The flight's light circles the space the camera is in.
        let (min, size) = spaces[4];
        let mid = [min[0] + 0.5 * size[0], min[1] + 0.5 * size[1], 1.0];
        let (origin, box_m) = crate::synth::scanned::flight_light_box(&scene, mid);
        assert_eq!(origin, min);
        assert_eq!([box_m[0], box_m[1]], size);
    }

    #[test]
    fn zero_frames_is_an_error() {
        let tmp = tempfile::tempdir().expect("tmp");
        let err = write_sequence(tmp.path(), &options("ideal", 0), &mut |_| {}).unwrap_err();
        assert!(matches!(err, SequenceError::FrameCount { found: 0 }));
    }
}
