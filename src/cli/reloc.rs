//! `star reloc build`: renders the relocalization database of a map (see
//! [`crate::reloc`]) with a progress bar and writes it to a file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use crate::config::Config;
use crate::dataset::{CameraFile, Trajectory};
use crate::reloc::{build_database_along, AlongTrajectory};

/// `star reloc` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum RelocCommand {
    /// Render views on a grid in the map's free space and write their
    /// descriptors and poses to a database file.
    Build(BuildArgs),
}

/// Arguments of `star reloc build`.
#[derive(Debug, clap::Args)]
pub struct BuildArgs {
    /// Map mesh (.obj, .ply, .gltf or .glb); default: the config's `map.mesh`.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Output database file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Configuration file: `[reloc]` grid, `[render]` renderer, and
    /// `[camera.intrinsics]` unless `--camera` is given.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Camera calibration file (a dataset's `camera.toml`); overrides the config's intrinsics.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// A trajectory (TUM: `stamp tx ty tz qx qy qz qw`, world_from_camera)
    /// where the vehicle will fly, such as the scanning run's or an earlier
    /// flight's: views along it are added to the grid's, with
    /// perturbations (half a yaw step either way, half a spacing to either
    /// side), and landmark views every `landmark_spacing_m`.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The frame of `--poses`: `world` (as `star` writes trajectories), or
    /// `mesh` (the mesh file's own frame, such as a scanner's poses), placed
    /// by `[map.world_from_mesh]`.
    #[arg(long, value_enum, default_value_t = PosesFrame::World)]
    pub poses_frame: PosesFrame,
    /// Distance between the views taken along `--poses`, meters (default:
    /// half the grid spacing).
    #[arg(long)]
    pub poses_spacing_m: Option<f64>,
}

/// The frame a `--poses` trajectory is given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PosesFrame {
    /// The z-up world frame.
    World,
    /// The mesh file's frame, placed by `[map.world_from_mesh]`.
    Mesh,
}

/// Runs a `star reloc` subcommand.
pub fn run(cmd: &RelocCommand) -> Result<()> {
    match cmd {
        RelocCommand::Build(args) => build(args),
    }
}

fn build(args: &BuildArgs) -> Result<()> {
    let config = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let camera = match &args.camera {
        Some(p) => {
            CameraFile::read(p)
                .with_context(|| format!("reading camera {}", p.display()))?
                .camera
        }
        None => config.camera.intrinsics,
    };
    let map_path = args.map.clone().unwrap_or_else(|| config.map.mesh.clone());
    let mesh = Arc::new(
        config
            .map
            .load_mesh_from(&map_path)
            .with_context(|| format!("loading map {}", map_path.display()))?,
    );
    let along = match &args.poses {
        Some(path) => {
            let spacing_m = args
                .poses_spacing_m
                .unwrap_or(0.5 * config.reloc.grid_spacing_m);
            if !(spacing_m.is_finite() && spacing_m > 0.0) {
                anyhow::bail!("--poses-spacing-m must be a positive distance, found {spacing_m}");
            }
            let trajectory = Trajectory::read(path)
                .with_context(|| format!("reading the trajectory {}", path.display()))?;
            if trajectory.is_empty() {
                anyhow::bail!("the trajectory {} has no poses", path.display());
            }
            let poses = match args.poses_frame {
                PosesFrame::World => trajectory.poses,
                PosesFrame::Mesh => {
                    let t = &config.map.world_from_mesh;
                    let world_from_mesh = t.rigid().to_pose();
                    trajectory
                        .poses
                        .iter()
                        .map(|mesh_from_camera| {
                            let mut p = *mesh_from_camera;
                            p.translation.vector *= t.scale;
                            world_from_mesh * p
                        })
                        .collect()
                }
            };
            AlongTrajectory { poses, spacing_m }
        }
        None => AlongTrajectory::default(),
    };
    let kind = config.render.renderer;
    let mut renderer =
        crate::render::select::make_configured_renderer(&config.render, mesh.clone())
            .with_context(|| format!("starting the `{kind:?}` renderer"))?;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} reloc build [{bar:40}] {pos}/{len} views and positions {per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let t0 = std::time::Instant::now();
    let db = build_database_along(
        &mesh,
        &camera,
        renderer.as_mut(),
        &config.reloc,
        None,
        &along,
        &mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    )
    .with_context(|| format!("building the database of {}", map_path.display()))?;
    bar.finish_and_clear();
    db.write(&args.output)?;
    println!(
        "reloc build: wrote {} keyframes and {} landmarks to {} in {:.1} s (renderer {}, map fingerprint {:#018x})",
        db.entries.len(),
        db.landmarks.len(),
        args.output.display(),
        t0.elapsed().as_secs_f64(),
        renderer.name(),
        db.map_fingerprint
    );
    Ok(())
}
