//! `star reloc build`: renders the relocalization database of a map (see
//! [`crate::reloc`]) on every core, with a progress bar, resumable from
//! its checkpoint, and writes it to a file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use crate::config::Config;
use crate::dataset::{CameraFile, Trajectory};
use crate::reloc::{
    build_parallel, checkpoint_path, AlongTrajectory, BuildError, BuildOptions, StageTimes,
};

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
    /// Worker threads, each with its own CPU rasterizer (default: one per
    /// core). The database is the same for any count, byte for byte.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Resume an interrupted build from the checkpoint next to the output
    /// (`OUTPUT.partial`). A build always resumes from a checkpoint of the
    /// same map, camera and settings; with `--resume` a missing one is an
    /// error instead of a fresh start.
    #[arg(long)]
    pub resume: bool,
    /// Stop after this many work units (grid positions, trajectory samples,
    /// landmark views), keeping the checkpoint: an interruption at a known
    /// point, for the tests.
    #[arg(long, hide = true)]
    pub stop_after_units: Option<usize>,
    /// Render only every N-th work unit and print where the time went and
    /// what the whole build would take on these cores (no database is
    /// written, the checkpoint is left alone).
    #[arg(long, value_name = "N")]
    pub sample_every: Option<usize>,
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
    // One CPU rasterizer per worker: it draws the same, bit for bit, for
    // any thread count, so the database does not depend on the cores.
    let threads = args.threads.unwrap_or(0);
    let checkpoint = checkpoint_path(&args.output);
    if args.resume && !checkpoint.exists() {
        anyhow::bail!(
            "--resume: no checkpoint {} to resume from",
            checkpoint.display()
        );
    }
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} reloc build [{bar:40}] {pos}/{len} positions and views {per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let t0 = std::time::Instant::now();
    // The far limit of `[render]` as in tracking: a building's views skip
    // the rooms beyond it.
    let far_m = config.render.far_limit_m();
    // Part of the checkpoint's key: views drawn with another far limit
    // are not resumed.
    // The level of detail of `[render]` too: the thumbnails are where it
    // saves the most (a scan's triangles are far below their pixels).
    let lod_px = config.render.lod_px();
    let renderer_name = if lod_px > 0.0 {
        format!("cpu far {far_m:?} lod {lod_px} px")
    } else {
        format!("cpu far {far_m:?}")
    };
    // One chunked copy of the map (and its levels of detail) for all the
    // build's threads. It draws both sides of every triangle whatever
    // `[render] cull_back_faces` says: the views stand for what a camera
    // sees, drawn as the dataset's images are (culled, the building
    // floor's database got 9 % more landmarks from the same map, a change
    // not traced further), and the clearance probes must see the inside
    // of a box the view stands in.
    let first_renderer = crate::render::cpu::CpuRenderer::with_lod(mesh.clone(), lod_px)
        .context("starting the CPU rasterizer on the map")?;
    let make_renderer = || Ok(first_renderer.share());
    let mut progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let sample_every = args.sample_every.unwrap_or(1);
    if sample_every == 0 {
        anyhow::bail!("--sample-every must be at least 1");
    }
    let mut times = StageTimes::default();
    let built = build_parallel(
        &mesh,
        &camera,
        &config.reloc,
        None,
        &along,
        &renderer_name,
        &make_renderer,
        BuildOptions {
            threads,
            checkpoint: Some(checkpoint.clone()),
            stop_after: args.stop_after_units,
            progress: &mut progress,
            sample_every,
            stage_times: Some(&mut times),
            far_m,
        },
    );
    bar.finish_and_clear();
    let db = match built {
        Ok(db) => db,
        Err(e @ BuildError::Stopped { .. }) => {
            println!("reloc build: {e}; run the same command again to resume");
            return Ok(());
        }
        Err(e) => {
            return Err(e)
                .with_context(|| format!("building the database of {}", map_path.display()))
        }
    };
    let wall_s = t0.elapsed().as_secs_f64();
    println!("reloc build: {times}");
    if sample_every > 1 {
        println!(
            "reloc build: sampled every {sample_every}th work unit: {} keyframes and {} landmarks in {wall_s:.1} s ({:.1} s in the stages); the whole build would take about {:.0} s on these cores (nothing written)",
            db.entries.len(),
            db.landmarks.len(),
            times.total_s(),
            wall_s * sample_every as f64,
        );
        return Ok(());
    }
    let size_bytes = db.write(&args.output)?;
    if let Err(e) = std::fs::remove_file(&checkpoint) {
        tracing::warn!(path = %checkpoint.display(), error = %e, "could not remove the build checkpoint");
    }
    println!(
        "reloc build: wrote {} keyframes and {} landmarks ({} vocabulary leaves) to {} ({:.1} MB) in {:.1} s (CPU rasterizer, {} threads, map fingerprint {:#018x})",
        db.entries.len(),
        db.landmarks.len(),
        db.vocabulary.leaves.len(),
        args.output.display(),
        size_bytes as f64 / 1e6,
        t0.elapsed().as_secs_f64(),
        if threads == 0 { rayon::current_num_threads() } else { threads },
        db.map_fingerprint
    );
    Ok(())
}
