//! `star bench`: benchmarks that print figures (never pass/fail).
//!
//! - `star bench pairs OUT`: writes keyframe/frame pairs from the synthetic
//!   scene (keyframe gray + 16-bit depth rendered from the map with holes,
//!   camera frame rendered from the truth with occluders, gain/bias drift,
//!   vignetting and noise; pinhole, so other trackers can use them as-is),
//!   with the ground-truth relative pose.
//! - `star bench track PAIRS`: aligns each pair with the STAR tracker on one
//!   thread from the identity, and prints time and error per pair and in
//!   summary. `scripts/bench_vs_opencv.py` runs OpenCV's RGB odometry on the
//!   same pairs and prints both side by side.
//! - `star bench integrity`: wrong poses sent, cold starts, kidnaps and
//!   wrong hints ([`crate::bench::integrity`]).
//! - `star bench reloc`: relocalization success rate and timings on the
//!   synthetic realistic scene ([`crate::bench::reloc`]).

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::bench::pairs::{track_pairs, write_pairs};

/// `star bench` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum BenchCommand {
    /// Write keyframe/frame pairs with ground truth for tracker benchmarks.
    Pairs {
        /// Output folder.
        out: PathBuf,
        /// Number of pairs.
        #[arg(long, default_value_t = 100)]
        count: usize,
        /// Seed of the scene, poses and noise.
        #[arg(long, default_value_t = 7)]
        seed: u64,
    },
    /// Align every pair of a `bench pairs` folder and print time and error.
    Track {
        /// Folder written by `star bench pairs`.
        pairs: PathBuf,
        /// Also write per-pair results as CSV here.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Align each pair this many times (the pyramid rebuilt each time,
        /// as for a new frame against the same keyframe) and time each pair
        /// by the median; 1 times a single, cold alignment.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=1000))]
        repeat: u32,
    },
    /// Integrity under faults: wrong poses sent, cold starts without a
    /// pose, kidnaps and wrong initial hints on a synthetic sequence, paced
    /// at 50 Hz, with the time each takes to recover.
    Integrity {
        /// Configuration file; default settings otherwise.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Preset of the sequence (`star synth --list-presets`).
        #[arg(long, default_value = "realistic")]
        preset: String,
        /// Seed of the sequence and of the random starts.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Frames of the sequence.
        #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(300..=20000))]
        frames: u64,
        /// Cold starts, kidnaps and wrong hints, each.
        #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
        trials: u64,
        /// Keep the sequence in this folder.
        #[arg(long)]
        keep: Option<PathBuf>,
        /// The scanned variant of the preset (`star synth --scanned`): the
        /// map is rebuilt by TSDF fusion of a noisy scan, and the flight
        /// has a moving light and auto-exposure steps.
        #[arg(long)]
        scanned: bool,
        /// Run on this existing `star synth` dataset instead of writing one
        /// (its `star.toml`, when present, places the map); `--preset`,
        /// `--scanned` and `--frames` are then ignored.
        #[arg(long, conflicts_with_all = ["keep", "scanned"])]
        dataset: Option<PathBuf>,
        /// Relocalization database over the flown region: read from this
        /// file when it exists (and matches the map), else built and
        /// written there (a heavy map's database takes minutes).
        #[arg(long)]
        database: Option<PathBuf>,
        /// Add views along the scanning run to the database (`star reloc
        /// build --poses`), from the scanned dataset's
        /// `scan_groundtruth.txt`.
        #[arg(long)]
        scan_views: bool,
        /// Kinds of trial to run: a comma-separated list of `cold`,
        /// `kidnap`, `hint` (each kind draws its places from its own
        /// seeded stream, so one kind alone repeats its trials).
        #[arg(long, default_value = "all")]
        kinds: crate::bench::integrity::TrialKinds,
    },
    /// Relocalization on the synthetic realistic scene: success rate,
    /// retrieval distance, search and recovery time.
    Reloc {
        /// Configuration file (its `[reloc]` section); default settings otherwise.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Number of query poses.
        #[arg(long, default_value_t = 100)]
        queries: usize,
        /// Seed of the scene and the queries.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Query random frames of this existing `star synth` dataset (its
        /// own images, e.g. a `--scanned` one, whose `star.toml` places the
        /// map) instead of rendering a scene of `--seed`.
        #[arg(long)]
        dataset: Option<PathBuf>,
        /// With `--dataset`: the relocalization database over the region it
        /// flies through, read when the file exists, else built and written
        /// there (the database of `star bench integrity --database`).
        #[arg(long, requires = "dataset")]
        database: Option<PathBuf>,
        /// With `--dataset`: also search each query from a kidnapped prior,
        /// the last known pose at another frame of the flight 1.5-5 m away,
        /// lost long enough to reach half that distance (the truth beyond
        /// reach) and then past the truth (within reach): what the service
        /// faces after a kidnap, or a loss it did not see at once.
        #[arg(long, requires = "dataset")]
        kidnaps: bool,
        /// Also draw the map from above (PNG) with the database's views and
        /// each whole-map query marked by its outcome (`star map plan`).
        #[arg(long)]
        plan: Option<PathBuf>,
    },
}

/// Runs a `star bench` subcommand.
pub fn run(cmd: &BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Pairs { out, count, seed } => write_pairs(out, *count, *seed),
        BenchCommand::Track { pairs, csv, repeat } => {
            track_pairs(pairs, csv.as_deref(), *repeat as usize)
        }
        BenchCommand::Integrity {
            config,
            preset,
            seed,
            frames,
            trials,
            keep,
            scanned,
            dataset,
            database,
            scan_views,
            kinds,
        } => {
            let config = match config {
                Some(p) => crate::config::Config::load(p)
                    .with_context(|| format!("loading config {}", p.display()))?,
                None => crate::config::Config::default(),
            };
            crate::bench::integrity::run(&crate::bench::integrity::IntegrityOptions {
                preset: preset.clone(),
                seed: *seed,
                frames: *frames as usize,
                trials: *trials as usize,
                config,
                keep: keep.clone(),
                scanned: *scanned,
                dataset: dataset.clone(),
                database: database.clone(),
                scan_views: *scan_views,
                kinds: *kinds,
            })
        }
        BenchCommand::Reloc {
            config,
            queries,
            seed,
            dataset,
            database,
            kidnaps,
            plan,
        } => {
            let source = dataset
                .as_ref()
                .map(|dataset| crate::bench::reloc::DatasetSource {
                    dataset: dataset.clone(),
                    database: database.clone(),
                    kidnaps: *kidnaps,
                });
            crate::bench::reloc::run(
                config.as_deref(),
                *queries,
                *seed,
                source.as_ref(),
                plan.as_deref(),
            )
        }
    }
}
