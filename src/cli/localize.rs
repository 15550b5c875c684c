//! `star localize`: run the STAR loop over a recorded dataset and write the
//! estimated trajectory (TUM format), with a progress bar and a timing and
//! quality summary. Exits non-zero when a frame could not be read (missing,
//! truncated, wrong size, not a regular file) or nothing was tracked.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use crate::config::Config;
use crate::dataset::Dataset;
use crate::offline::{
    localize_dataset_recorded, median_p99, OfflineOptions, OfflineReport, OfflineSinks, StartMode,
};
use crate::reloc::{map_fingerprint, RelocDatabase, Relocalizer};

use super::pose_arg::parse_pose;
use super::record_arg::{print_record_summary, RecordArgs};
use super::rerun_arg::RerunArgs;

/// Arguments of `star localize`.
#[derive(Debug, clap::Args)]
pub struct LocalizeArgs {
    /// Dataset folder (TUM layout with camera.toml).
    pub dataset: PathBuf,
    /// Map mesh (default: DATASET/map/map.obj).
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Output trajectory, TUM format.
    #[arg(short, long, default_value = "est.txt")]
    pub output: PathBuf,
    /// Initial pose "tx ty tz qx qy qz qw" (world_from_camera); default: the
    /// ground truth at the first frame.
    #[arg(long)]
    pub init_pose: Option<String>,
    /// Configuration file (tracker, keyframe policy, renderer).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Process at most N frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Deliver frames at the recorded rate, as a live camera would.
    #[arg(long)]
    pub realtime: bool,
    /// Relocalization database (`star reloc build`): relocalize when lost.
    #[arg(long)]
    pub reloc: Option<PathBuf>,
    /// How the run starts: `trusted` tracks from the start pose at once
    /// (the benchmarks' setting); `hint` verifies it through the
    /// relocalization gate first, as in flight; `cold` has no start pose and
    /// searches the database (needs --reloc), as in flight without a hint.
    #[arg(long, value_enum, default_value = "trusted")]
    pub start: StartArg,
    /// The flight log.
    #[command(flatten)]
    pub record: RecordArgs,
    /// The live view.
    #[command(flatten)]
    pub rerun: RerunArgs,
}

/// `--start`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum StartArg {
    /// Track from the start pose at once.
    Trusted,
    /// Verify the start pose through the relocalization gate first.
    Hint,
    /// No start pose: search the relocalization database.
    Cold,
}

/// Runs `star localize`.
pub fn run(args: &LocalizeArgs) -> Result<()> {
    let config = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let dataset = Dataset::open(&args.dataset)
        .with_context(|| format!("opening dataset {}", args.dataset.display()))?;
    args.rerun.target()?;
    let mut record = args.record.start(&config, dataset.camera())?;
    if !args.realtime {
        // Not paced: nothing to keep up with, so every row and picture.
        if let Some(r) = record.as_mut() {
            r.wait_for_writer();
        }
    }
    let mut sinks = OfflineSinks::with_record(record);
    let map_path = args
        .map
        .clone()
        .unwrap_or_else(|| args.dataset.join("map").join("map.obj"));
    let mesh = Arc::new(
        config
            .map
            .load_mesh_from(&map_path)
            .with_context(|| format!("loading map {}", map_path.display()))?,
    );
    let relocalizer = match &args.reloc {
        Some(path) => {
            let db = RelocDatabase::read(path)?;
            db.check_compatible(dataset.camera(), map_fingerprint(&mesh))?;
            Some(Relocalizer::new(db, &config.reloc, dataset.camera())?.with_map(&mesh))
        }
        None => None,
    };
    #[cfg(feature = "rerun")]
    {
        sinks.rerun = args.rerun.start(dataset.camera(), &config.tracker, || {
            Ok(crate::output::rerun_log::RerunStatics {
                mesh: Some(mesh.clone()),
                ground_truth: dataset.ground_truth.clone(),
            })
        })?;
    }
    let kind = config.render.renderer;
    let renderer = crate::render::select::make_configured_renderer(&config.render, mesh)
        .with_context(|| format!("starting the `{kind:?}` renderer"))?;
    let world_from_camera_start = args.init_pose.as_deref().map(parse_pose).transpose()?;
    let options = OfflineOptions {
        world_from_camera_start,
        max_frames: args.max_frames,
        realtime: args.realtime,
        relocalizer,
        start: match args.start {
            StartArg::Trusted => StartMode::Trusted,
            StartArg::Hint => StartMode::Hint,
            StartArg::Cold => StartMode::Cold,
        },
    };
    let n = options
        .max_frames
        .map_or(dataset.len(), |m| m.min(dataset.len()));
    let bar = ProgressBar::new(n as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} localize [{bar:40}] {pos}/{len} frames {per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let report = localize_dataset_recorded(
        &dataset,
        renderer,
        &config,
        &options,
        |_| bar.inc(1),
        (!sinks.is_empty()).then_some(&mut sinks),
    )?;
    bar.finish_and_clear();
    let record = sinks.record.take().map(crate::output::RecordSink::finish);
    #[cfg(feature = "rerun")]
    let rerun = sinks
        .rerun
        .take()
        .map(crate::output::rerun_log::RerunSink::finish);
    report
        .estimate
        .write(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    print_summary(&report, &args.output);
    if !report.record_ms.is_empty() {
        let (median_ms, p99_ms) = median_p99(&report.record_ms);
        println!(
            "  flight log / live view hand-off per frame: median {:.1} us, p99 {:.1} us",
            median_ms * 1e3,
            p99_ms * 1e3
        );
    }
    if let Some(record) = &record {
        print_record_summary("localize", record);
    }
    #[cfg(feature = "rerun")]
    if let Some(rerun) = &rerun {
        super::rerun_arg::print_rerun_summary("localize", rerun);
    }
    check_report(&report)
}

/// A run whose dataset had unreadable frames, or that tracked nothing,
/// failed: the trajectory is written, and the error says why.
fn check_report(report: &OfflineReport) -> Result<()> {
    if let Some((index, first)) = report.bad_frames.first() {
        anyhow::bail!(
            "{} frames could not be used ({} processed); the first, frame {index}: {first}",
            report.bad_frames.len(),
            report.frames
        );
    }
    if report.estimate.is_empty() {
        anyhow::bail!(
            "tracked nothing: {} frames processed, {} lost, none tracked",
            report.frames,
            report.lost_frames
        );
    }
    Ok(())
}

/// "tracking lost N times: REASON n, ..." from the losses by reason, or
/// `None` when tracking was never lost.
fn losses_line(losses: &[u64]) -> Option<String> {
    let total: u64 = losses.iter().sum();
    if total == 0 {
        return None;
    }
    let parts: Vec<String> = crate::localizer::LossReason::ALL
        .iter()
        .zip(losses)
        .filter(|(_, &n)| n > 0)
        .map(|(r, n)| format!("{} {n}", r.name()))
        .collect();
    Some(format!(
        "tracking lost {total} times, by the first test failed: {}",
        parts.join(", ")
    ))
}

/// Prints the end-of-run summary.
pub fn print_summary(report: &OfflineReport, output: &Path) {
    let (median_ms, p99_ms) = median_p99(&report.track_ms);
    println!(
        "localize: wrote {} poses to {}",
        report.estimate.len(),
        output.display()
    );
    println!(
        "  frames {}  tracked {}  lost {}  bad {}  skipped while busy {}  renderer {}",
        report.frames,
        report.estimate.len(),
        report.lost_frames,
        report.bad_frames.len(),
        report.skipped_frames,
        report.renderer
    );
    println!(
        "  tracking time per frame: median {median_ms:.2} ms, p99 {p99_ms:.2} ms; points per level (median) {:?}",
        report.median_points
    );
    println!(
        "  keyframes {}  frames tracked on a stale keyframe {}  largest keyframe age {:.3} s",
        report.keyframes, report.stale_frames, report.max_keyframe_age_s
    );
    println!(
        "  quality over tracked frames: lowest inlier ratio {:.3}, lowest correlation {:.3}",
        report.min_inlier_ratio, report.min_correlation
    );
    if let Some(line) = losses_line(&report.losses) {
        println!(
            "  {line}; {} resumes held a frame for confirmation; {} keyframes followed the camera through short losses",
            report.held_resumes, report.lost_keyframes
        );
    }
    if let Some(withheld) = report.held_for_next_frame {
        println!(
            "  poses held for the next frame ([keyframe] hold_for_next_frame): {withheld} tracked frames not sent, the frame after each lost"
        );
    }
    if report.reloc_attempts > 0 || report.relocalizations > 0 {
        println!(
            "  relocalization: {} attempts, {} relocalized, {} verifying frames passed by tracking (reset_counter {})",
            report.reloc_attempts,
            report.relocalizations,
            report.verified_by_tracking,
            report.reset_counters.last().copied().unwrap_or(0)
        );
    }
    if let Some(i) = &report.integrity {
        let first = i
            .first_pose_after_s
            .map_or("none".to_string(), |s| format!("{s:.2} s"));
        println!(
            "  integrity: wrong poses sent {} of {} checked (> {} cm or > {} deg from the truth); largest error {:.2} cm / {:.2} deg; first pose after {first}",
            i.wrong_poses,
            i.poses_checked,
            crate::offline::WRONG_POSITION_M * 100.0,
            crate::offline::WRONG_ROTATION_DEG,
            i.max_position_error_m * 100.0,
            i.max_rotation_error_deg
        );
    }
    if let Some(e) = &report.evaluation {
        println!(
            "  ATE (no alignment, {} matched): translation rmse {:.2} cm, mean {:.2} cm, max {:.2} cm; rotation rmse {:.3} deg, max {:.3} deg",
            e.matched,
            e.ate.translation_m.rmse * 100.0,
            e.ate.translation_m.mean * 100.0,
            e.ate.translation_m.max * 100.0,
            e.ate.rotation_deg.rmse,
            e.ate.rotation_deg.max
        );
    }
}

#[cfg(test)]
mod tests {
    use super::losses_line;
    use crate::localizer::LossReason;

    #[test]
    fn losses_line_names_each_reason_counted() {
        assert_eq!(losses_line(&[0; LossReason::ALL.len()]), None);
        let mut losses = [0u64; LossReason::ALL.len()];
        losses[LossReason::LocalContrast.index()] = 2;
        losses[LossReason::Jump.index()] = 1;
        let line = losses_line(&losses).expect("losses");
        assert_eq!(
            line,
            "tracking lost 3 times, by the first test failed: \
             jump from the prediction (lost_max_jump_m/_deg) 1, \
             local contrast (track_min_local_correlation) 2"
        );
    }
}
