//! `star calib import FILE`: a camera calibration from OpenCV (FileStorage
//! YAML or XML), Kalibr (`camchain.yaml`) or ROS (`camera_info` YAML) as the
//! `[camera.intrinsics]` section of star's config: printed, written to a
//! file (`-o`), or merged into an existing config (`--merge`). The reading
//! and the checks are [`crate::calib`]'s.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use crate::calib::{import_file, merge::merge_intrinsics, Calibration};
use crate::config::Config;

/// `star calib` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum CalibCommand {
    /// Read a calibration (OpenCV FileStorage YAML/XML, Kalibr camchain.yaml,
    /// ROS camera_info YAML; detected from the content) and write star's
    /// `[camera.intrinsics]` section.
    Import(ImportArgs),
}

/// Arguments of `star calib import`.
#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// The calibration file.
    pub file: PathBuf,
    /// The camera of a Kalibr camchain with several (default: cam0).
    #[arg(long)]
    pub camera: Option<String>,
    /// Write the section to this file instead of stdout.
    #[arg(short, long, conflicts_with = "merge")]
    pub output: Option<PathBuf>,
    /// Replace `[camera.intrinsics]` in this star config in place, keeping
    /// the rest of it (comments included); the result is validated first.
    #[arg(long)]
    pub merge: Option<PathBuf>,
}

/// Runs a `star calib` subcommand.
pub fn run(cmd: &CalibCommand) -> Result<()> {
    match cmd {
        CalibCommand::Import(args) => import(args),
    }
}

fn import(args: &ImportArgs) -> Result<()> {
    let calibration = import_file(&args.file, args.camera.as_deref())?;
    let detected = describe(&args.file, &calibration);
    match (&args.output, &args.merge) {
        (Some(out), _) => {
            std::fs::write(out, calibration.to_toml(&args.file))
                .with_context(|| format!("writing {}", out.display()))?;
            println!("{detected}; wrote [camera.intrinsics] to {}", out.display());
        }
        (None, Some(config)) => {
            merge(config, &calibration)?;
            println!(
                "{detected}; replaced [camera.intrinsics] in {}",
                config.display()
            );
        }
        (None, None) => {
            eprintln!("{detected}");
            print!("{}", calibration.to_toml(&args.file));
        }
    }
    Ok(())
}

fn describe(file: &Path, calibration: &Calibration) -> String {
    let c = &calibration.camera;
    let name = match &calibration.camera_name {
        Some(n) => format!(", camera {n}"),
        None => String::new(),
    };
    format!(
        "calib: {}: detected {}{name}: {}x{}, fx {} fy {} cx {} cy {}",
        file.display(),
        calibration.format,
        c.width,
        c.height,
        c.fx,
        c.fy,
        c.cx,
        c.cy
    )
}

/// Replaces the intrinsics of `config`, validates the result as a star
/// config, and writes it through a temporary file and a rename (a crash
/// leaves the old config or the new one, never half of one).
fn merge(config: &Path, calibration: &Calibration) -> Result<()> {
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("--merge: reading {}", config.display()))?;
    let merged = merge_intrinsics(&text, &calibration.camera)
        .with_context(|| format!("--merge: {}", config.display()))?;
    Config::parse(&merged, config).context("--merge: the config with these intrinsics")?;
    let tmp = config.with_extension("toml.calib-tmp");
    std::fs::write(&tmp, merged).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, config)
        .with_context(|| format!("renaming {} to {}", tmp.display(), config.display()))?;
    Ok(())
}
