//! `star run`: the camera and the tracker in one process, on two threads,
//! still talking through iceoryx2 (the same code path as two processes).
//!
//! The tracker starts first (map, first keyframe, READY), then the camera
//! thread; when the camera thread ends (a replay without loop), the tracker
//! finishes the frames in flight and stops. With a `replay:` source the
//! calibration is the dataset's `camera.toml`.
//!
//! Exits non-zero when the camera source failed (a replay frame missing,
//! truncated, of the wrong size or not a regular file) or when the run
//! tracked nothing, after the trajectory is flushed and the summary printed.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};
use tracing::{info, warn};

use crate::camera::{run_camera, RunnerSettings, SourceUri};
use crate::config::Config;
use crate::ipc::{create_node, load_iceoryx_config, FramePublisher};

use super::track::{finish, initial_pose, load_config, stop_when, TrackArgs};
use crate::tracker::start;

/// Options of `star run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Tracker options.
    #[command(flatten)]
    pub track: TrackArgs,
    /// Camera source URI overriding `camera.source`.
    #[arg(long)]
    pub source: Option<String>,
}

/// Sets the flag when dropped (also when the camera thread panics).
struct DoneFlag(Arc<AtomicBool>);

impl Drop for DoneFlag {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Runs `star run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let shutdown = crate::service::signals::install_shutdown_handler()?;
    let mut config = load_config(&args.track)?;
    if let Some(source) = &args.source {
        config.camera.source = source.clone();
    }
    let uri = SourceUri::parse(&config.camera.source).context("camera source")?;
    if let SourceUri::Replay(dir) = &uri {
        let dataset = crate::dataset::Dataset::open(dir)
            .with_context(|| format!("opening dataset {}", dir.display()))?;
        config.camera.intrinsics = *dataset.camera();
    }
    let hint = initial_pose(args.track.init_pose.as_deref(), &config)?;
    let mut stop = stop_when(&args.track, &config)?;
    let tracker = match start(&config, hint, shutdown.clone()) {
        Ok(tracker) => tracker,
        Err(e) if e.is::<crate::tracker::StoppedDuringStart>() => {
            println!("track: {e}");
            return Ok(());
        }
        Err(e) => return Err(e),
    };
    let done = Arc::new(AtomicBool::new(false));
    let camera = {
        let (config, shutdown, done) = (config.clone(), shutdown.clone(), done.clone());
        std::thread::Builder::new()
            .name("camera".into())
            .spawn(move || {
                let _done = DoneFlag(done);
                let result = camera_thread(&config, &uri, &shutdown);
                if let Err(e) = &result {
                    warn!(error = format!("{e:#}"), "camera thread failed");
                }
                result
            })
            .context("starting the camera thread")?
    };
    stop.source_done = Some(done);
    let summary = tracker.run(&mut stop);
    // Stop the camera too when the tracker ended first.
    shutdown.store(true, Ordering::Relaxed);
    let camera_result = match camera.join() {
        Ok(result) => result,
        Err(_) => Err(anyhow::anyhow!("the camera thread panicked")),
    };
    let summary = summary?;
    let tracked = finish(&summary, args.track.trajectory.as_deref());
    // The source's failure says more than "tracked nothing".
    camera_result.context("the camera source failed")?;
    tracked
}

fn camera_thread(config: &Config, uri: &SourceUri, shutdown: &AtomicBool) -> Result<()> {
    let settings = config.camera.source_settings();
    let open = super::camera::source_opener(config, uri, &settings)?;
    let iox =
        load_iceoryx_config(&config.ipc.iceoryx2_config, None).context("iceoryx2 configuration")?;
    let node = create_node("star-camera", &iox).context("iceoryx2 node")?;
    let mut publisher = FramePublisher::new(&node).context("frame publisher")?;
    info!(source = %uri, "camera thread started");
    let stop = || shutdown.load(Ordering::Relaxed);
    let summary = run_camera(open, &mut publisher, &stop, &RunnerSettings::default())
        .with_context(|| format!("camera {uri}"))?;
    info!(
        published = summary.stats.published,
        ended = summary.ended,
        "camera thread stopped"
    );
    println!("camera: frames published {}", summary.stats.published);
    Ok(())
}
