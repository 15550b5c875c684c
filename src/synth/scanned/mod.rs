//! The `scanned` variant of a synthetic sequence: a map rebuilt the way a
//! user builds one, and flight images that no longer come from the same
//! renderer, light and frame as the map.
//!
//! Every other preset is a closed world: the camera images and the map are
//! drawn by the same renderer from the same textured boxes. A map made by
//! TSDF fusion of a real RGB-D scan differs from what the camera sees:
//! vertex colors at voxel resolution (blurred), the scan's lighting baked
//! in, geometric noise, holes where the scan did not look, and a frame of
//! its own (the scanner's first camera, y down). This module builds such a
//! map for the synthetic scene:
//!
//! 1. [`scan_path`]: a seeded scanning walk around the room at 1.2-1.6 m,
//!    one lap looking at the walls, one looking into the room and down
//!    (not everywhere: holes remain);
//! 2. each scan frame is rendered from the scene's map mesh (no holes, no
//!    occluders) by the CPU rasterizer; [`lighting`] shades it with the
//!    scan's fixed point light (normals from the rendered depth), plus
//!    sensor noise; [`depth_sensor`] turns the ideal depth into a
//!    structured-light measurement (noise growing with depth squared, 1 mm
//!    quantization, dropouts at grazing angles and edges, 4 m range);
//! 3. [`fusion`]: Open3D fuses the frames tile by tile (uniform TSDF
//!    volumes, 1 cm voxels) into a vertex-colored mesh, in the frame of the
//!    first scan camera perturbed by a small seeded registration error;
//! 4. the mesh is written to `map/map.obj` (`v x y z r g b`, `f a b c`),
//!    and `star.toml` next to the dataset declares `[map.world_from_mesh]`
//!    = the first scan camera's pose (as a user would measure it, without
//!    the registration error).
//!
//! The flight images are then rendered from the truth mesh under a
//! different, moving light ([`lighting::MovingLightSpec`]) with
//! auto-exposure steps ([`exposure`]), on top of the preset's sensor model
//! (see `synth::sequence`).

pub mod depth_sensor;
pub mod exposure;
pub mod fusion;
pub mod lighting;
pub mod scan_path;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

use self::depth_sensor::{DepthSensorSpec, Gaussian};
use self::exposure::ExposureSpec;
use self::fusion::{check_python, run_fusion, FusionJob, FusionStats};
use self::lighting::{depth_normals, shade, LightSpec, MovingLightSpec, PointLight};
use self::scan_path::{LapLook, ScanLap, ScanPath, ScanPathError, ScanPathSpec};
use super::corrupt::derive_seed;
use super::scene::Scene;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::{MapError, Mesh};
use crate::render::cpu::CpuRenderer;
use crate::render::{RenderError, RenderedView, Renderer};

/// Every parameter of the scanned variant (printed in `synth.toml`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScannedSpec {
    /// The scanning walk.
    pub scan_path: ScanPathSpec,
    /// Frames fused per second of the walk.
    pub scan_rate_hz: f64,
    /// The scan's RGB-D camera (ideal pinhole; depth and color registered).
    pub scan_camera: PinholeCamera,
    /// Its depth errors.
    pub depth_sensor: DepthSensorSpec,
    /// Gaussian noise of its color images, gray levels.
    pub scan_color_noise_sigma: f64,
    /// The light at scan time (fixed, near the ceiling at a seeded place),
    /// baked into the map's colors.
    pub scan_light: LightSpec,
    /// Distance of the scan light below the ceiling, meters.
    pub scan_light_below_ceiling_m: f64,
    /// TSDF voxel edge, meters.
    pub voxel_m: f64,
    /// TSDF truncation distance, in voxels.
    pub sdf_trunc_voxels: f64,
    /// Fusion tile edge, meters.
    pub tile_m: f64,
    /// Tile overlap, voxels.
    pub tile_overlap_voxels: u32,
    /// Size of the map's registration error: translation, meters.
    pub registration_error_m: f64,
    /// Size of the map's registration error: rotation, degrees.
    pub registration_error_deg: f64,
    /// The light during the flight (moving).
    pub flight_light: MovingLightSpec,
    /// Auto-exposure steps during the flight.
    pub exposure: ExposureSpec,
}

impl Default for ScannedSpec {
    fn default() -> Self {
        Self {
            scan_path: ScanPathSpec {
                speed_mps: 0.4,
                laps: vec![
                    ScanLap {
                        look: LapLook::Outward,
                        wall_distance_m: 1.6,
                        pitch_bias_deg: -5.0,
                    },
                    ScanLap {
                        look: LapLook::Inward,
                        wall_distance_m: 1.0,
                        pitch_bias_deg: -30.0,
                    },
                ],
                height_m: (1.2, 1.6),
                height_period_s: 13.0,
                position_wobble_m: 0.1,
                yaw_wobble_deg: 40.0,
                pitch_wobble_deg: 15.0,
                roll_wobble_deg: 3.0,
                wobble_hz: (0.03, 0.12),
                clearance_m: 0.3,
            },
            scan_rate_hz: 2.5,
            scan_camera: PinholeCamera::new(640, 480, 525.0, 525.0, 319.5, 239.5),
            depth_sensor: DepthSensorSpec::STRUCTURED_LIGHT,
            scan_color_noise_sigma: 2.0,
            scan_light: LightSpec {
                ambient: 0.55,
                diffuse: 0.9,
                falloff_m: 3.0,
            },
            scan_light_below_ceiling_m: 0.3,
            voxel_m: 0.01,
            sdf_trunc_voxels: 4.0,
            tile_m: 1.5,
            tile_overlap_voxels: 3,
            registration_error_m: 0.01,
            registration_error_deg: 0.3,
            flight_light: MovingLightSpec {
                light: LightSpec {
                    ambient: 0.5,
                    diffuse: 1.0,
                    falloff_m: 3.5,
                },
                below_ceiling_m: 0.4,
                radius_fraction: 0.6,
                period_s: 20.0,
            },
            exposure: ExposureSpec {
                step_interval_s: (1.0, 2.0),
                step_fraction: (0.15, 0.25),
                gain_range: (0.6, 1.6),
            },
        }
    }
}

/// Why the scanned map could not be built.
#[derive(Debug, thiserror::Error)]
pub enum ScannedError {
    /// No scanning walk fits the room.
    #[error("cannot place the scanning walk")]
    Path(#[from] ScanPathError),
    /// Rendering a scan frame failed.
    #[error("rendering a scan frame")]
    Render(#[from] RenderError),
    /// The fused mesh is invalid, or writing it failed.
    #[error("the scanned map")]
    Map(#[from] MapError),
    /// Reading or writing a file failed.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Python could not be started.
    #[error("cannot run {python} for the TSDF fusion (Open3D): {reason}; set --python, STAR_PYTHON or STAR_VENV to a Python with open3d (hil_tests/requirements.txt)")]
    Python {
        /// The interpreter tried.
        python: PathBuf,
        /// The error.
        reason: String,
    },
    /// The fusion script failed or gave unreadable output.
    #[error("TSDF fusion failed: {0}")]
    Fusion(String),
    /// The fused mesh is empty (the scan saw nothing).
    #[error("the TSDF fusion produced an empty mesh")]
    EmptyMesh,
}

/// Where the tools of the fusion are.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanTools {
    /// The Python interpreter with open3d.
    pub python: PathBuf,
}

impl ScanTools {
    /// `STAR_PYTHON`, else `$STAR_VENV/bin/python`, else `./.venv/bin/python`
    /// when it exists, else `python3`.
    pub fn from_env() -> Self {
        let python = std::env::var_os("STAR_PYTHON")
            .map(PathBuf::from)
            .or_else(|| {
                std::env::var_os("STAR_VENV").map(|v| PathBuf::from(v).join("bin").join("python"))
            })
            .or_else(|| {
                let local = PathBuf::from(".venv/bin/python");
                local.exists().then_some(local)
            })
            .unwrap_or_else(|| PathBuf::from("python3"));
        Self { python }
    }
}

/// What [`build_scanned_map`] made.
#[derive(Debug, Clone)]
pub struct ScannedMap {
    /// The map mesh file, `map/map.obj`, in the mesh (scanner) frame.
    pub obj_path: PathBuf,
    /// The fused mesh as written (mesh frame).
    pub mesh: Mesh,
    /// The declared placement: the first scan camera's pose, without the
    /// registration error (what `star.toml` says).
    pub world_from_mesh_declared: Pose,
    /// The actual placement of the fused vertices (declared times the
    /// registration error): `p_world = world_from_mesh_true * p_mesh` up to
    /// the fusion's own errors.
    pub world_from_mesh_true: Pose,
    /// The scanning walk.
    pub scan_path: ScanPath,
    /// The scan's light, per lap of the walk (one per room, or per space of
    /// a building).
    pub scan_lights: Vec<PointLight>,
    /// Frames fused.
    pub scan_frames: usize,
    /// Time rendering and corrupting the scan frames, seconds.
    pub scan_render_s: f64,
    /// The fusion's statistics.
    pub fusion: FusionStats,
}

/// The scanning walk of `scene` for `seed`. It avoids the room's walls and
/// the furniture; the occluders (objects absent from the map) were not
/// there at scan time. A building is scanned space by space: the same laps
/// in every room, in door order, then in the corridor (whose laps are
/// long, thin ellipses along it), each space's walk drawn from a seed of
/// its own; the walker steps from one space to the next between two frames.
pub fn scan_path_for(
    scene: &Scene,
    spec: &ScannedSpec,
    seed: u64,
) -> Result<ScanPath, ScanPathError> {
    if let Some(plan) = &scene.plan {
        let is_free = |p: [f64; 3], margin_m: f64| {
            plan.is_free(p, margin_m) && !scene.furniture.iter().any(|b| b.contains(p, margin_m))
        };
        let mut walk: Option<ScanPath> = None;
        for (k, (min_m, size_m)) in plan.spaces().into_iter().enumerate() {
            let part = ScanPath::generate_in(
                &spec.scan_path,
                min_m,
                [size_m[0], size_m[1], plan.spec.height_m],
                derive_seed(seed, 0x5ca_0000 + k as u64),
                &is_free,
            )?;
            walk = Some(match walk {
                None => part,
                Some(walk) => walk.then(part),
            });
        }
        return walk.ok_or(ScanPathError::NoLaps);
    }
    let is_free = |p: [f64; 3], margin_m: f64| {
        (0..3).all(|k| p[k] >= margin_m && p[k] <= scene.room_size_m[k] - margin_m)
            && !scene.furniture.iter().any(|b| b.contains(p, margin_m))
    };
    ScanPath::generate(
        &spec.scan_path,
        scene.room_size_m,
        derive_seed(seed, 0x5ca),
        &is_free,
    )
}

/// A seeded registration error of translation `meters` and rotation
/// `degrees` in random directions.
pub fn registration_error(meters: f64, degrees: f64, seed: u64) -> Pose {
    let mut rng = Gaussian::new(derive_seed(seed, 0x7e9));
    let mut unit = || {
        let v = Vector3::new(rng.normal(), rng.normal(), rng.normal());
        v.try_normalize(1e-12).unwrap_or_else(Vector3::x)
    };
    let t = unit() * meters;
    let axis = unit();
    Pose::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_scaled_axis(axis * degrees.to_radians()),
    )
}

/// The scan light's (fixed) position for `seed`: near the ceiling, within
/// the middle half of the room.
pub fn scan_light(spec: &ScannedSpec, room_size_m: [f64; 3], seed: u64) -> PointLight {
    let mut rng = Gaussian::new(derive_seed(seed, 0x119));
    let [lx, ly, lz] = room_size_m;
    PointLight {
        position_m: Vector3::new(
            lx * (0.25 + 0.5 * rng.uniform()),
            ly * (0.25 + 0.5 * rng.uniform()),
            lz - spec.scan_light_below_ceiling_m,
        ),
        spec: spec.scan_light,
    }
}

/// The scan light of each lap of `path` (the walk [`scan_path_for`] drew
/// for `scene` and `seed`): the room's one light, or in a building one per
/// space (each room's and the corridor's, [`scan_light`] placed in that
/// space).
pub fn scan_lights(
    scene: &Scene,
    spec: &ScannedSpec,
    seed: u64,
    path: &ScanPath,
) -> Vec<PointLight> {
    let Some(plan) = &scene.plan else {
        return vec![scan_light(spec, scene.room_size_m, seed); path.lap_count()];
    };
    let laps_per_space = spec.scan_path.laps.len();
    plan.spaces()
        .iter()
        .enumerate()
        .flat_map(|(k, (min_m, size_m))| {
            let mut light = scan_light(
                spec,
                [size_m[0], size_m[1], plan.spec.height_m],
                derive_seed(seed, 0x119_0000 + k as u64),
            );
            light.position_m.x += min_m[0];
            light.position_m.y += min_m[1];
            std::iter::repeat_n(light, laps_per_space)
        })
        .collect()
}

/// Where the flight's moving light circles when the camera is at
/// `p_world`: the room (`origin`, `size`), or in a building the space the
/// camera is in (the corridor when it stands in a doorway).
pub fn flight_light_box(scene: &Scene, p_world: [f64; 3]) -> ([f64; 2], [f64; 3]) {
    let Some(plan) = &scene.plan else {
        return ([0.0, 0.0], scene.room_size_m);
    };
    let spaces = plan.spaces();
    let k = plan
        .space_at(p_world)
        .unwrap_or(spaces.len().saturating_sub(1));
    spaces
        .get(k)
        .map_or(([0.0, 0.0], scene.room_size_m), |(min_m, size_m)| {
            (*min_m, [size_m[0], size_m[1], plan.spec.height_m])
        })
}

fn matrix_rows(pose: &Pose) -> [f64; 16] {
    let m: Matrix4<f64> = pose.to_homogeneous();
    let mut out = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[4 * r + c] = m[(r, c)];
        }
    }
    out
}

/// Builds the scanned map of `scene` into `map_dir/map.obj`: renders the
/// scanning run into `work_dir`, fuses it with Open3D, writes the mesh in
/// the scanner's frame. `progress(done, total)` is called per scan frame.
pub fn build_scanned_map(
    scene: &Scene,
    spec: &ScannedSpec,
    seed: u64,
    map_dir: &Path,
    work_dir: &Path,
    tools: &ScanTools,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ScannedMap, ScannedError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ScannedError::Io { path, source }
    };
    // Fail before the scan is rendered when the fusion cannot run.
    let open3d = check_python(&tools.python)?;
    tracing::info!(python = %tools.python.display(), open3d, "TSDF fusion through Open3D");
    let path = scan_path_for(scene, spec, seed)?;
    let frames = ((path.duration_s() * spec.scan_rate_hz).round() as usize).max(1);
    let world_from_mesh_declared = path.pose_at(0.0);
    let world_from_mesh_true = world_from_mesh_declared
        * registration_error(spec.registration_error_m, spec.registration_error_deg, seed);
    let mesh_from_world = world_from_mesh_true.inverse();
    let lights = scan_lights(scene, spec, seed, &path);

    // Render the scanning run.
    let started = Instant::now();
    std::fs::create_dir_all(work_dir).map_err(io(work_dir))?;
    let gray_path = work_dir.join("scan_gray.u8");
    let depth_path = work_dir.join("scan_depth.u16");
    let mut gray_file =
        std::io::BufWriter::new(std::fs::File::create(&gray_path).map_err(io(&gray_path))?);
    let mut depth_file =
        std::io::BufWriter::new(std::fs::File::create(&depth_path).map_err(io(&depth_path))?);
    let camera = spec.scan_camera;
    let mut renderer = CpuRenderer::new(Arc::new(scene.map.clone()))?;
    let mut view = RenderedView::for_camera(&camera);
    let mut normals = Vec::new();
    let mut depth_mm = Vec::new();
    let mut gray_u8 = Vec::new();
    let mut depth_bytes = Vec::new();
    let mut mesh_from_camera = Vec::with_capacity(frames);
    for i in 0..frames {
        let t_s = path.duration_s() * i as f64 / frames as f64;
        let world_from_camera = path.pose_at(t_s);
        let Some(light) = lights.get(path.lap_index_at(t_s)) else {
            return Err(ScannedError::Path(ScanPathError::NoLaps));
        };
        renderer.render(&world_from_camera, &camera, &mut view)?;
        depth_normals(&view.depth_m, &camera, &mut normals);
        shade(
            &mut view.gray,
            &view.depth_m,
            &normals,
            &camera,
            &world_from_camera,
            light,
        );
        let frame_seed = derive_seed(seed, 0x5ca0_0000 + i as u64);
        let mut noise = Gaussian::new(derive_seed(frame_seed, 1));
        gray_u8.clear();
        gray_u8.extend(view.gray.data().iter().map(|&g| {
            (g as f64 + spec.scan_color_noise_sigma * noise.normal())
                .round()
                .clamp(0.0, 255.0) as u8
        }));
        spec.depth_sensor.measure(
            &view.depth_m,
            &normals,
            &camera,
            derive_seed(frame_seed, 2),
            &mut depth_mm,
        );
        depth_bytes.clear();
        depth_bytes.extend(depth_mm.iter().flat_map(|d| d.to_le_bytes()));
        gray_file.write_all(&gray_u8).map_err(io(&gray_path))?;
        depth_file
            .write_all(&depth_bytes)
            .map_err(io(&depth_path))?;
        mesh_from_camera.push(matrix_rows(&(mesh_from_world * world_from_camera)));
        progress(i + 1, frames);
    }
    gray_file.flush().map_err(io(&gray_path))?;
    depth_file.flush().map_err(io(&depth_path))?;
    drop((gray_file, depth_file));
    let scan_render_s = started.elapsed().as_secs_f64();

    // The room's box in the mesh frame.
    let margin = 0.1;
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for corner in 0..8 {
        let c = Point3::new(
            if corner & 1 == 0 {
                -margin
            } else {
                scene.room_size_m[0] + margin
            },
            if corner & 2 == 0 {
                -margin
            } else {
                scene.room_size_m[1] + margin
            },
            if corner & 4 == 0 {
                -margin
            } else {
                scene.room_size_m[2] + margin
            },
        );
        let p = mesh_from_world * c;
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let job = FusionJob {
        width: camera.width,
        height: camera.height,
        fx: camera.fx,
        fy: camera.fy,
        cx: camera.cx,
        cy: camera.cy,
        frames,
        gray_path,
        depth_path,
        mesh_from_camera,
        depth_scale: 1000.0,
        depth_trunc_m: spec.depth_sensor.max_range_m,
        voxel_m: spec.voxel_m,
        sdf_trunc_m: spec.sdf_trunc_voxels * spec.voxel_m,
        tile_m: spec.tile_m,
        overlap_voxels: spec.tile_overlap_voxels,
        bounds_min: lo,
        bounds_max: hi,
        assign_step_px: 4,
        assign_min_points: 16,
        out_prefix: work_dir.join("fused"),
    };
    let (mesh, fusion) = run_fusion(&tools.python, &job, work_dir)?;
    if mesh.indices.is_empty() {
        return Err(ScannedError::EmptyMesh);
    }
    let obj_path = write_colored_obj(&mesh, map_dir, "map")?;
    Ok(ScannedMap {
        obj_path,
        mesh,
        world_from_mesh_declared,
        world_from_mesh_true,
        scan_path: path,
        scan_lights: lights,
        scan_frames: frames,
        scan_render_s,
        fusion,
    })
}

/// Writes a vertex-colored mesh as a scanner would: `v x y z r g b` (gray
/// replicated, 0..1, 4 decimals; positions to 10 micrometers) and
/// `f a b c`, no materials. Returns the path.
pub fn write_colored_obj(mesh: &Mesh, dir: &Path, stem: &str) -> Result<PathBuf, ScannedError> {
    mesh.validate()?;
    std::fs::create_dir_all(dir).map_err(|source| ScannedError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let path = dir.join(format!("{stem}.obj"));
    let io = |source| ScannedError::Io {
        path: path.clone(),
        source,
    };
    let mut out = std::io::BufWriter::new(std::fs::File::create(&path).map_err(io)?);
    let body = |out: &mut std::io::BufWriter<std::fs::File>| -> std::io::Result<()> {
        writeln!(
            out,
            "# written by star synth (scanned): TSDF-fused vertex-colored mesh, scanner frame"
        )?;
        for (p, &g) in mesh.positions.iter().zip(&mesh.gray) {
            let c = (g / 255.0).clamp(0.0, 1.0);
            writeln!(
                out,
                "v {:.5} {:.5} {:.5} {c:.4} {c:.4} {c:.4}",
                p[0], p[1], p[2]
            )?;
        }
        for t in mesh.indices.chunks_exact(3) {
            writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
        }
        out.flush()
    };
    body(&mut out).map_err(io)?;
    Ok(path)
}

/// The text of `DATASET/star.toml`: `[map] mesh` and `[map.world_from_mesh]`
/// (the declared placement), with a comment saying what it is.
pub fn star_toml_text(obj_path: &Path, world_from_mesh: &Pose) -> String {
    let t = world_from_mesh.translation.vector;
    let q = world_from_mesh.rotation.quaternion();
    let mesh = obj_path
        .display()
        .to_string()
        .replace('\\', "\\\\")
        .replace('"', "\\\"");
    format!(
        "# Written by `star synth` (scanned): the map of this dataset was rebuilt by TSDF\n\
         # fusion of a scanning run and is stored in the scanner's frame (its first\n\
         # camera's optical frame: x right, y down, z forward). This section places it\n\
         # in the z-up world, as a user would measure it (the map also carries a small\n\
         # registration error that this transform does not know about). Use it with\n\
         #   star localize DATASET --config DATASET/star.toml\n\
         [map]\n\
         mesh = \"{mesh}\"\n\n\
         [map.world_from_mesh]\n\
         translation_m = [{:?}, {:?}, {:?}]\n\
         quaternion_wxyz = [{:?}, {:?}, {:?}, {:?}]\n\
         scale = 1.0\n",
        t.x, t.y, t.z, q.w, q.i, q.j, q.k
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_registration_error_has_the_requested_size() {
        for seed in 0..8 {
            let e = registration_error(0.01, 0.3, seed);
            assert!((e.translation.vector.norm() - 0.01).abs() < 1e-12);
            assert!((e.rotation.angle().to_degrees() - 0.3).abs() < 1e-9);
        }
        assert_ne!(
            registration_error(0.01, 0.3, 1),
            registration_error(0.01, 0.3, 2)
        );
    }

    #[test]
    fn star_toml_round_trips_the_placement() {
        let pose = Pose::from_parts(
            Translation3::new(1.5, 2.25, 1.4),
            UnitQuaternion::from_euler_angles(-1.7, 0.1, 0.6),
        );
        let text = star_toml_text(Path::new("/data/scan 1/map/map.obj"), &pose);
        // The `[map]` section as the config reads it (the whole `Config` is
        // checked by tests/synth_scanned.rs: `config` sits above `synth`).
        #[derive(serde::Deserialize)]
        struct MapOnly {
            map: crate::map::MapConfig,
        }
        let parsed: MapOnly = toml::from_str(&text).expect("valid TOML with a [map] section");
        let map = parsed.map;
        map.validate().expect("valid placement");
        assert_eq!(map.mesh, PathBuf::from("/data/scan 1/map/map.obj"));
        let back = map.world_from_mesh.rigid().to_pose();
        assert!((back.translation.vector - pose.translation.vector).norm() < 1e-12);
        assert!(back.rotation.angle_to(&pose.rotation) < 1e-12);
    }
}
