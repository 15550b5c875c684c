//! `star camera`: the camera process. Reads the configured (or `--source`)
//! camera and publishes its frames on the iceoryx2 frame service until a stop
//! signal (SIGTERM, SIGINT, SIGHUP, SIGQUIT, SIGUSR1), reconnecting when the
//! camera fails. [`source_opener`] opens any source, the `sim:` camera too
//! (for `star run` as well).

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result};
use tracing::{info, warn};

use crate::camera::{
    open_source, run_camera, CameraError, FrameSource, RunnerSettings, SourceSettings, SourceUri,
};
use crate::config::Config;
use crate::ipc::{create_node, load_iceoryx_config, FramePublisher};
use crate::service::{signals, Service};
use crate::synth::sim_camera::{SimCamera, SimSettings};

/// Options of `star camera`.
#[derive(Debug, clap::Args)]
pub struct CameraArgs {
    /// Configuration file; built-in defaults when the default path does not exist.
    #[arg(long, default_value = "/etc/star/star.toml")]
    pub config: PathBuf,
    /// Source URI overriding `camera.source`: v4l2:/dev/videoN, aravis:ID
    /// (aravis:fake for the built-in fake camera), replay:DIR, pattern:WxH,
    /// sim:LINK[?scene=DIR&origin=LAT,LON,ALT] (a simulated vehicle's camera).
    #[arg(long)]
    pub source: Option<String>,
    /// Stop after publishing this many frames.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Replay speed factor (overrides `camera.replay_speed`).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Loop the replay (overrides `camera.replay_loop`).
    #[arg(long = "loop")]
    pub looping: bool,
}

/// Loads `path`, or the defaults when `path` is the default one and absent.
pub(crate) fn load_config_or_default(path: &Path) -> Result<Config> {
    if path == Path::new("/etc/star/star.toml") && !path.exists() {
        warn!(path = %path.display(), "config not found, using built-in defaults");
        return Ok(Config::default());
    }
    Config::load(path).with_context(|| format!("loading {}", path.display()))
}

/// Opens a camera source, again after each failure: what
/// [`run_camera`] calls.
pub(crate) type SourceOpener = Box<dyn FnMut() -> Result<Box<dyn FrameSource>, CameraError> + Send>;

/// The opener of `uri`. A `sim:` camera loads its scene here, once (an
/// error names the dataset), and takes the intrinsics, the rate and the
/// `[mavlink]` transforms from `config`; other sources open with `settings`.
pub(crate) fn source_opener(
    config: &Config,
    uri: &SourceUri,
    settings: &SourceSettings,
) -> Result<SourceOpener> {
    let SourceUri::Sim(sim) = uri else {
        let (uri, settings) = (uri.clone(), settings.clone());
        return Ok(Box::new(move || open_source(&uri, &settings)));
    };
    anyhow::ensure!(
        config.map.world_from_mesh == crate::map::MeshTransformConfig::default(),
        "camera {uri}: a sim: camera needs [map.world_from_mesh] to be the identity \
         (a `star synth` map is in the world frame)"
    );
    let sim = SimCamera::new(
        sim,
        &config.map.mesh,
        SimSettings {
            camera: config.camera.intrinsics,
            fps: config.camera.fps,
            ned_from_world: config.mavlink.ned_from_world.to_pose(),
            body_from_camera: config.mavlink.body_from_camera.to_pose(),
            frame_timeout_ms: config.camera.frame_timeout_ms,
        },
    )
    .with_context(|| format!("camera {uri}"))?;
    info!(
        scene = %sim.scene().dir.display(),
        preset = sim.scene().preset,
        "sim camera scene loaded"
    );
    Ok(Box::new(move || sim.open()))
}

/// Runs the camera process.
pub fn run(args: &CameraArgs) -> Result<()> {
    let config = load_config_or_default(&args.config)?;
    let source_text = args.source.as_deref().unwrap_or(&config.camera.source);
    let uri = SourceUri::parse(source_text).context("camera source")?;
    let mut settings = config.camera.source_settings();
    if let Some(speed) = args.speed {
        anyhow::ensure!(
            crate::camera::replay_speed_is_sane(speed),
            "--speed must be within {}..={}, found {speed:?}",
            crate::camera::MIN_REPLAY_SPEED,
            crate::camera::MAX_REPLAY_SPEED
        );
        settings.replay_speed = speed;
    }
    settings.replay_loop |= args.looping;
    // A source that cannot be set up (a sim: scene) fails before the
    // frame service is taken.
    let open = source_opener(&config, &uri, &settings)?;
    // Before iceoryx2: see `signals::install_shutdown_handler`.
    let shutdown = signals::install_shutdown_handler()?;
    let iox =
        load_iceoryx_config(&config.ipc.iceoryx2_config, None).context("iceoryx2 configuration")?;
    let node = create_node("star-camera", &iox).context("iceoryx2 node")?;
    let mut publisher = FramePublisher::new(&node).context("frame publisher")?;
    // systemd: READY=1 once the publisher is up (star-camera.service is
    // Type=notify), and WATCHDOG=1 while the runner loop turns: it asks
    // `stop` between frames and while it waits to reconnect a camera.
    let service = Service::start(shutdown.clone()).context("service thread")?;
    let watchdog = service.watchdog();
    service.ready();
    info!(source = %uri, "camera process started");
    let stop = || {
        watchdog.feed();
        if shutdown.load(Ordering::Relaxed) {
            return true;
        }
        let stopping = node.wait(Duration::ZERO).is_err();
        if stopping {
            shutdown.store(true, Ordering::Relaxed);
        }
        stopping
    };
    let runner = RunnerSettings {
        max_frames: args.frames,
        ..RunnerSettings::default()
    };
    let summary = run_camera(open, &mut publisher, &stop, &runner)
        .with_context(|| format!("camera {uri}"))?;
    info!(
        published = summary.stats.published,
        rejected = summary.stats.rejected,
        source_errors = summary.stats.source_errors,
        skipped = summary.skipped,
        opens = summary.opens,
        "camera process stopped"
    );
    service.stop();
    Ok(())
}
