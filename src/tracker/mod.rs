//! The tracker process (`star track`, and the tracker thread of `star
//! run`): iceoryx2 frames in, poses out to the iceoryx2 pose service and to
//! the autopilot over MAVLink, the trajectory streamed to a file.
//!
//! [`start`] opens the ports, loads the map and the relocalization database,
//! starts the renderer, renders the first keyframe, starts the MAVLink link
//! and tells systemd the service is ready; [`Tracker::run`]
//! (`frame_loop.rs`) is the loop, until SIGTERM/SIGINT or a [`StopWhen`]
//! condition: [`Tracker::step`] (one iteration: one frame in, one pose out)
//! until it returns [`Step::Stop`], then [`Tracker::finish`]. It sits above `localizer`, `ipc`, `mavlink_io` and `service`,
//! and below `cli`, which only parses arguments and prints.

mod frame_loop;

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use tracing::info;

use crate::clock::monotonic_now_ns;
use crate::config::Config;
use crate::geometry::Pose;
use crate::ipc::{create_node, load_iceoryx_config, FrameSubscriber, PosePublisher};
use crate::localizer::Localizer;
use crate::mavlink_io::MavlinkLink;
use crate::reloc::{map_fingerprint, RelocDatabase, Relocalizer};
use crate::service::Service;

pub use frame_loop::{Step, StopReason, StopWhen, TrackSummary, Tracker, WrongSize};

/// A stop signal arrived while [`start`] loaded the map, the database or
/// the renderer: the start was abandoned between two of those steps.
#[derive(Debug, thiserror::Error)]
#[error("stopped by a signal while starting")]
pub struct StoppedDuringStart;

fn stopped_during_start(shutdown: &AtomicBool) -> Result<(), StoppedDuringStart> {
    if shutdown.load(std::sync::atomic::Ordering::Relaxed) {
        return Err(StoppedDuringStart);
    }
    Ok(())
}

/// Opens the ports, loads the map, renders the first keyframe, starts the
/// MAVLink link and tells systemd the service is ready.
///
/// The tracker starts `searching` and outputs nothing until a frame passes
/// the relocalization gate ([`Localizer::verify_start`]): `hint` (from
/// `--init-pose` or `tracker.init_pose`) is tried first; with a database
/// and no hint, the first frame is searched in the database (a cold
/// start). Without a database a hint is required.
///
/// A stop signal during the start ends it between steps with
/// [`StoppedDuringStart`] (which callers report as a clean stop).
pub fn start(config: &Config, hint: Option<Pose>, shutdown: Arc<AtomicBool>) -> Result<Tracker> {
    let iox =
        load_iceoryx_config(&config.ipc.iceoryx2_config, None).context("iceoryx2 configuration")?;
    let node = create_node("star-track", &iox).context("iceoryx2 node")?;
    let subscriber = FrameSubscriber::new(&node)
        .context("frame subscriber")?
        .with_spin(std::time::Duration::from_micros(config.ipc.spin_us));
    let poses = PosePublisher::new(&node).context("pose publisher")?;
    let service = Service::start(shutdown.clone()).context("service thread")?;
    let mesh = &config.map.mesh;
    let mesh_data = Arc::new(
        config
            .map
            .load_mesh()
            .with_context(|| format!("loading map {}", mesh.display()))?,
    );
    stopped_during_start(&shutdown)?;
    let relocalizer = match &config.reloc.database {
        Some(path) => {
            let db = RelocDatabase::read(path)?;
            db.check_compatible(&config.camera.intrinsics, map_fingerprint(&mesh_data))?;
            Some(
                Relocalizer::new(db, &config.reloc, &config.camera.intrinsics)?
                    .with_map(&mesh_data),
            )
        }
        None => None,
    };
    // Any pose of the map will do for the first keyframe of a cold start:
    // it is never tracked against before a relocalization replaces it.
    let world_from_camera_start = match (hint, &relocalizer) {
        (Some(pose), _) => pose,
        (None, Some(r)) => match r.database().entries.first() {
            Some(entry) => entry.world_from_camera,
            None => bail!("relocalization database {} has no views", r.database().path.display()),
        },
        (None, None) => bail!(
            "no initial pose and no relocalization database: set `tracker.init_pose` or pass --init-pose, or build a database (`star reloc build`) and set `reloc.database`"
        ),
    };
    stopped_during_start(&shutdown)?;
    let kind = config.render.renderer;
    let renderer = crate::render::select::make_configured_renderer(&config.render, mesh_data)
        .with_context(|| format!("starting the `{kind:?}` renderer"))?;
    let mut localizer = Localizer::start(
        renderer,
        &config.camera.intrinsics,
        &config.tracker,
        &config.keyframe,
        world_from_camera_start,
        monotonic_now_ns(),
    )
    .context("starting the tracker")?;
    if let Some(r) = relocalizer {
        localizer
            .set_relocalizer(r)
            .context("relocalization database")?;
    }
    stopped_during_start(&shutdown)?;
    localizer.verify_start(&config.reloc, hint.is_some());
    let mavlink = if config.mavlink.enabled {
        Some(MavlinkLink::spawn(&config.mavlink, shutdown.clone()).context("MAVLink link")?)
    } else {
        None
    };
    service.ready();
    info!(
        mesh = %mesh.display(),
        renderer = localizer.renderer_name(),
        "tracker ready; waiting for frames"
    );
    let looping = frame_loop::LoopState::new(&service, config.keyframe.hold_for_next_frame);
    Ok(Tracker {
        subscriber,
        poses,
        localizer,
        mavlink,
        service,
        shutdown,
        silence: Duration::from_millis(config.ipc.silence_timeout_ms),
        world_from_camera_start,
        looping,
        node,
    })
}
