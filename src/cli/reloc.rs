//! `star reloc build`: renders the relocalization database of a map (see
//! [`crate::reloc`]) with a progress bar and writes it to a file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use crate::config::Config;
use crate::dataset::CameraFile;
use crate::reloc::build_database;

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
    let kind = config.render.renderer;
    let mut renderer = crate::render::select::make_renderer(kind, mesh.clone())
        .with_context(|| format!("starting the `{kind:?}` renderer"))?;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} reloc build [{bar:40}] {pos}/{len} positions {per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let t0 = std::time::Instant::now();
    let db = build_database(
        &mesh,
        &camera,
        renderer.as_mut(),
        &config.reloc,
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
