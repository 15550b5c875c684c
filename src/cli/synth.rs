//! `star synth --preset NAME OUT`: write a synthetic TUM-layout dataset
//! (images, depth, ground truth, calibration, map mesh) from a named preset
//! and a seed, with a progress bar; `--list-presets` prints every preset's
//! exact parameters.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};

use crate::synth::preset::{Preset, PRESET_NAMES};
use crate::synth::sequence::{write_sequence, SequenceOptions};

/// Arguments of `star synth`.
#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Preset name (see `--list-presets`).
    #[arg(long, default_value = "realistic")]
    pub preset: String,
    /// Output dataset folder (created; files in it are overwritten).
    #[arg(required_unless_present = "list_presets")]
    pub out: Option<PathBuf>,
    /// Seed of the scene, the trajectory and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of frames (at the preset's 50 Hz).
    #[arg(long, default_value_t = 500)]
    pub frames: usize,
    /// Do not write depth images.
    #[arg(long)]
    pub no_depth: bool,
    /// Print every preset's exact parameters and exit.
    #[arg(long)]
    pub list_presets: bool,
}

/// Runs `star synth`.
pub fn run(args: &SynthArgs) -> Result<()> {
    if args.list_presets {
        for preset in Preset::all() {
            println!(
                "# preset `{}`: {}\n{}",
                preset.name,
                preset.description,
                preset.to_toml()
            );
        }
        return Ok(());
    }
    let Some(out) = args.out.as_ref() else {
        bail!("an output folder is required");
    };
    let Some(preset) = Preset::by_name(&args.preset) else {
        bail!(
            "unknown preset `{}`: expected one of {}",
            args.preset,
            PRESET_NAMES.join(", ")
        );
    };
    let options = SequenceOptions {
        preset,
        seed: args.seed,
        frames: args.frames,
        write_depth: !args.no_depth,
    };
    let bar = indicatif::ProgressBar::new(args.frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "synth {msg} [{bar:40}] {pos}/{len} frames, {per_sec}, eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message(args.preset.clone());
    let start = Instant::now();
    let summary =
        write_sequence(out, &options, &mut |n| bar.set_position(n as u64)).with_context(|| {
            format!(
                "synthesizing preset `{}` into {}",
                args.preset,
                out.display()
            )
        })?;
    bar.finish_and_clear();
    println!(
        "wrote {} frames of preset `{}` (seed {}) to {} in {:.1} s: {} renders, map {} ({} triangles)",
        summary.frames,
        args.preset,
        args.seed,
        summary.root.display(),
        start.elapsed().as_secs_f64(),
        summary.renders,
        summary.map_path.display(),
        summary.map_triangles
    );
    Ok(())
}
