//! The `star` command line: one subcommand per job, each in its own file.
//!
//! Every subcommand returns `anyhow::Result`; `main` prints the error chain
//! once and exits non-zero.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod bench;
mod calib;
mod camera;
mod check_config;
mod doctor;
mod eval;
pub mod localize;
mod map;
mod pose_arg;
mod record_arg;
mod reloc;
mod render;
mod replay;
mod rerun_arg;
mod run;
mod synth;
mod track;

/// STAR: monocular localization against a colored mesh map.
#[derive(Debug, Parser)]
#[command(name = "star", version, about, long_about = None)]
pub struct Cli {
    /// Log filter, e.g. `info` or `star=debug` (overrides RUST_LOG).
    #[arg(long, global = true)]
    pub log: Option<String>,
    /// The job to run.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Validate a configuration file, open every file it names (map,
    /// relocalization database, iceoryx2 config, replay dataset) and print
    /// the effective values.
    CheckConfig {
        /// The TOML file (default: /etc/star/star.toml).
        #[arg(default_value = "/etc/star/star.toml")]
        config: PathBuf,
        /// Check the values only; do not open the files the config names.
        #[arg(long)]
        values_only: bool,
    },
    /// Benchmarks that print figures (tracker pairs, ...).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Localize a recorded dataset against its map and write the trajectory.
    Localize(localize::LocalizeArgs),
    /// The map: `info` (size, floor, holes, render times, memory) and
    /// `align` (the `[map.world_from_mesh]` that makes it z-up).
    #[command(subcommand)]
    Map(map::MapCommand),
    /// Render the map at a pose (CPU rasterizer) to a gray PNG and a depth PNG.
    Render(render::RenderArgs),
    /// Absolute trajectory error (no alignment) and relative pose error of
    /// an estimated TUM trajectory against ground truth; flight-log counts
    /// and a plot on request.
    Eval(eval::EvalArgs),
    /// Camera calibration import (`star calib import FILE`: OpenCV, Kalibr
    /// or ROS to `[camera.intrinsics]`).
    #[command(subcommand)]
    Calib(calib::CalibCommand),
    /// Relocalization database (`star reloc build --map MESH -o DB`).
    #[command(subcommand)]
    Reloc(reloc::RelocCommand),
    /// Synthesize a TUM-layout dataset (images, depth, ground truth, map) from a preset.
    Synth(synth::SynthArgs),
    /// Run the camera process: read a camera and publish frames over iceoryx2.
    Camera(camera::CameraArgs),
    /// Play a dataset into a v4l2loopback device (virtual camera) or onto iceoryx2.
    Replay(replay::ReplayArgs),
    /// The tracker process: track iceoryx2 frames against the map, send
    /// poses to the pose service and to the autopilot (MAVLink).
    Track(track::TrackArgs),
    /// Camera and tracker in one process (two threads, through iceoryx2).
    Run(run::RunArgs),
    /// Check this machine: wgpu adapters, the renderer `auto` would choose,
    /// and a test render.
    Doctor {
        /// A config file whose `render.renderer` to test (default: `auto`).
        #[arg(long)]
        config: Option<PathBuf>,
    },
}

fn init_tracing(filter: Option<&str>) {
    use tracing_subscriber::EnvFilter;
    let filter = match filter {
        Some(f) => EnvFilter::new(f),
        None => EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info")),
    };
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// Parses the command line, runs the subcommand, and maps errors to an exit code.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    init_tracing(cli.log.as_deref());
    let result = match cli.command {
        Command::CheckConfig {
            config,
            values_only,
        } => check_config::run(&config, values_only),
        Command::Localize(args) => localize::run(&args),
        Command::Bench(cmd) => bench::run(&cmd),
        Command::Map(cmd) => map::run(&cmd),
        Command::Render(args) => render::run(&args),
        Command::Eval(args) => eval::run(&args),
        Command::Synth(args) => synth::run(&args),
        Command::Reloc(cmd) => reloc::run(&cmd),
        Command::Calib(cmd) => calib::run(&cmd),
        Command::Camera(args) => camera::run(&args),
        Command::Replay(args) => replay::run(&args),
        Command::Doctor { config } => doctor::run(config.as_deref()),
        Command::Track(args) => track::run(&args),
        Command::Run(args) => run::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_message(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, `: ` between them, each cause
/// written once: most of star's errors already name their cause in their
/// own message (`cannot read FILE: the I/O error`) and also return it as
/// their source, which `{:#}` would print a second time.
fn error_message(e: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if message.contains(&text) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::error_message;

    #[derive(Debug, thiserror::Error)]
    #[error("cannot read {path}: {source}")]
    struct ReadError {
        path: String,
        source: std::io::Error,
    }

    fn not_found() -> std::io::Error {
        std::io::Error::new(std::io::ErrorKind::NotFound, "no such file")
    }

    #[test]
    fn a_cause_the_message_already_names_is_written_once() {
        let e = anyhow::Error::new(ReadError {
            path: "map.obj".into(),
            source: not_found(),
        })
        .context("loading map map.obj");
        assert_eq!(
            error_message(&e),
            "loading map map.obj: cannot read map.obj: no such file"
        );
    }

    #[test]
    fn causes_not_in_the_message_are_each_appended() {
        let e = anyhow::Error::new(not_found())
            .context("opening camera.toml")
            .context("opening dataset ds");
        assert_eq!(
            error_message(&e),
            "opening dataset ds: opening camera.toml: no such file"
        );
    }
}
