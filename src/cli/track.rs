//! `star track`: the tracker process. Loads the config and the map, renders
//! the first keyframe at the initial pose, then tracks the frames the camera
//! process publishes on iceoryx2 and sends the poses to the pose service and
//! to the autopilot (MAVLink), until a stop signal (SIGTERM, SIGINT, SIGHUP,
//! SIGQUIT, SIGUSR1: all graceful, the trajectory flushed).
//!
//! Exits non-zero when the run tracked nothing (unless a signal stopped it
//! before any frame arrived), with a line saying why.
//!
//! The initial pose comes from `--init-pose` or `tracker.init_pose`
//! ([`initial_pose`]). With a relocalization database (`reloc.database` or
//! `--reloc`), a lost tracker searches it and restarts on its own.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};

use crate::config::Config;
use crate::dataset::TrajectoryWriter;
use crate::geometry::Pose;
use crate::service::signals;
use crate::tracker::{start, StopReason, StopWhen, StoppedDuringStart, TrackSummary};

use super::pose_arg::parse_pose;
use super::record_arg::{print_record_summary, RecordArgs};
use super::rerun_arg::RerunArgs;

/// Options shared by `star track` and `star run`.
#[derive(Debug, Clone, clap::Args)]
pub struct TrackArgs {
    /// Configuration file (must exist).
    #[arg(long, default_value = "/etc/star/star.toml")]
    pub config: PathBuf,
    /// Initial pose "tx ty tz qx qy qz qw" (world_from_camera, TUM order);
    /// overrides `tracker.init_pose`.
    #[arg(long)]
    pub init_pose: Option<String>,
    /// Map mesh overriding `map.mesh`.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// MAVLink connection overriding `mavlink.connection`.
    #[arg(long)]
    pub mavlink: Option<String>,
    /// Stream the tracked poses to this file as they are produced (TUM
    /// format, flushed at least once a second; replay sources are stamped in
    /// dataset time).
    #[arg(long)]
    pub trajectory: Option<PathBuf>,
    /// Relocalization database (`star reloc build`) overriding
    /// `reloc.database`.
    #[arg(long)]
    pub reloc: Option<PathBuf>,
    /// Stop after this many frames.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Stop after this many seconds without a frame, once frames arrived.
    #[arg(long)]
    pub idle_exit_s: Option<f64>,
    /// The flight log.
    #[command(flatten)]
    pub record: RecordArgs,
    /// The live view.
    #[command(flatten)]
    pub rerun: RerunArgs,
}

/// The initial pose hint: `--init-pose`, else `tracker.init_pose`, else
/// none (a cold start, which needs a relocalization database). Either way
/// it is verified before any pose goes out.
pub fn initial_pose(arg: Option<&str>, config: &Config) -> Result<Option<Pose>> {
    if let Some(text) = arg {
        return parse_pose(text).context("--init-pose").map(Some);
    }
    match config.tracker.world_from_camera_init {
        Some([tx, ty, tz, qx, qy, qz, qw]) => {
            parse_pose(&format!("{tx} {ty} {tz} {qx} {qy} {qz} {qw}"))
                .context("tracker.init_pose")
                .map(Some)
        }
        None => Ok(None),
    }
}

/// Loads the config (which must exist) and applies the command-line overrides.
pub fn load_config(args: &TrackArgs) -> Result<Config> {
    let mut config =
        Config::load(&args.config).with_context(|| format!("config {}", args.config.display()))?;
    if let Some(map) = &args.map {
        config.map.mesh = map.clone();
    }
    if let Some(connection) = &args.mavlink {
        config.mavlink.connection = connection.clone();
        config
            .validate(&args.config)
            .context("--mavlink connection")?;
    }
    if let Some(db) = &args.reloc {
        config.reloc.database = Some(db.clone());
    }
    if !config.map.mesh.is_file() {
        bail!(
            "map mesh {} does not exist (map.mesh in {}, or --map)",
            config.map.mesh.display(),
            args.config.display()
        );
    }
    if let Some(s) = args.idle_exit_s {
        // A day: beyond it the option means "never", and a huge value would
        // not fit a Duration.
        if !(s > 0.0 && s <= 86_400.0) {
            bail!("--idle-exit-s must be within 0 < s <= 86400, found {s:?}");
        }
    }
    Ok(config)
}

/// The stop conditions given on the command line; creates the trajectory
/// file and starts the flight log and the live view, so a bad
/// `--trajectory`, `--record` or `--rerun` fails before the run, not after
/// it.
pub fn stop_when(args: &TrackArgs, config: &Config) -> Result<StopWhen> {
    args.rerun.target()?;
    let trajectory = match &args.trajectory {
        Some(path) => Some(
            TrajectoryWriter::create(path)
                .with_context(|| format!("--trajectory {}", path.display()))?,
        ),
        None => None,
    };
    Ok(StopWhen {
        frames: args.frames,
        idle: args.idle_exit_s.map(Duration::from_secs_f64),
        source_done: None,
        trajectory,
        record: args.record.start(config, &config.camera.intrinsics)?,
        #[cfg(feature = "rerun")]
        rerun: args
            .rerun
            .start(&config.camera.intrinsics, &config.tracker, || {
                // The tracker loads the map too; the live view shows it once.
                let mesh = config.map.load_mesh().with_context(|| {
                    format!("loading map {} for --rerun", config.map.mesh.display())
                })?;
                Ok(crate::output::rerun_log::RerunStatics {
                    mesh: Some(std::sync::Arc::new(mesh)),
                    ground_truth: None,
                })
            })?,
    })
}

/// Runs `star track`.
pub fn run(args: &TrackArgs) -> Result<()> {
    let shutdown = signals::install_shutdown_handler()?;
    let config = load_config(args)?;
    let hint = initial_pose(args.init_pose.as_deref(), &config)?;
    let mut stop = stop_when(args, &config)?;
    let tracker = match start(&config, hint, shutdown) {
        Ok(tracker) => tracker,
        Err(e) if e.is::<StoppedDuringStart>() => {
            println!("track: {e}");
            return Ok(());
        }
        Err(e) => return Err(e),
    };
    let summary = tracker.run(&mut stop)?;
    finish(&summary, args.trajectory.as_deref())
}

/// Writes the trajectory (when asked) and prints the summary.
pub fn finish(summary: &TrackSummary, trajectory: Option<&Path>) -> Result<()> {
    if let (Some(path), Some(poses)) = (trajectory, summary.trajectory_poses) {
        println!("track: wrote {poses} poses to {}", path.display());
    }
    if let Some(record) = &summary.record {
        print_record_summary("track", record);
    }
    #[cfg(feature = "rerun")]
    if let Some(rerun) = &summary.rerun {
        super::rerun_arg::print_rerun_summary("track", rerun);
    }
    let rate = if summary.frames > 0 {
        100.0 * summary.tracked as f64 / summary.frames as f64
    } else {
        0.0
    };
    let fps = if summary.active_s > 0.0 {
        summary.frames.saturating_sub(1) as f64 / summary.active_s
    } else {
        0.0
    };
    println!(
        "track: frames processed {}  tracked {} ({rate:.1} %)  lost {}  rejected {} (wrong size {})  dropped {}  camera restarts {}  keyframes {}  {fps:.1} fps  renderer {}",
        summary.frames,
        summary.tracked,
        summary.lost,
        summary.rejected,
        summary.wrong_size.frames,
        summary.dropped,
        summary.publisher_changes,
        summary.keyframes,
        summary.renderer
    );
    if let Some(withheld) = summary.held_for_next_frame {
        println!(
            "track: poses held for the next frame ([keyframe] hold_for_next_frame): {withheld} tracked frames not sent, the frame after each lost"
        );
    }
    match &summary.link {
        Some(s) => println!(
            "track: MAVLink sent VISION_POSITION_ESTIMATE {}  ODOMETRY {}  HEARTBEAT {}  TIMESYNC requests {}  TIMESYNC replies {}; dropped: lost {} rate {} stale {} link {} clock {} spacing {}; autopilot heartbeats {}",
            s.vision_position_estimate_sent,
            s.odometry_sent,
            s.heartbeat_sent,
            s.timesync_requests_sent,
            s.timesync_replies_sent,
            s.poses_dropped_lost,
            s.poses_dropped_rate,
            s.poses_dropped_stale,
            s.poses_dropped_link,
            s.poses_dropped_clock,
            s.poses_dropped_spacing,
            s.autopilot_heartbeats
        ),
        None => println!("track: MAVLink disabled"),
    }
    check_tracked(summary)
}

/// A run that tracked nothing failed, with one exception: a tracker stopped
/// by a signal before any frame arrived (`systemctl stop` of an idle
/// service) did nothing wrong.
pub fn check_tracked(summary: &TrackSummary) -> Result<()> {
    if summary.tracked > 0 {
        return Ok(());
    }
    let frames_seen = summary.frames + summary.rejected;
    if frames_seen == 0 && summary.stop_reason == Some(StopReason::Shutdown) {
        println!("track: stopped by a signal before any frame arrived");
        return Ok(());
    }
    if frames_seen == 0 {
        bail!("tracked nothing: no frame arrived from the camera");
    }
    let wrong = &summary.wrong_size;
    if let (0, Some((w, h)), Some((cw, ch))) = (summary.frames, wrong.found, wrong.calibrated) {
        bail!(
            "tracked nothing: {} frames refused because they are {w}x{h} and the calibration ([camera.intrinsics]) is {cw}x{ch}; calibrate the camera at the size it delivers (`star calib import`) or make it deliver {cw}x{ch}",
            wrong.frames
        );
    }
    bail!(
        "tracked nothing: {} frames processed ({} lost) and {} rejected, none tracked",
        summary.frames,
        summary.lost,
        summary.rejected
    )
}
