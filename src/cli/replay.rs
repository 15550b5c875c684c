//! `star replay DATASET`: plays a TUM-layout dataset at its recorded rate
//! (times `--speed`), either into a v4l2loopback device (`--to /dev/videoN`,
//! the virtual camera for hardware-in-the-loop runs) or, without `--to`, onto
//! the iceoryx2 frame service like `star camera --source replay:DATASET`.

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::camera::replay::ReplaySource;
use crate::camera::SourceUri;

/// Options of `star replay`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Dataset folder (TUM layout: rgb.txt, rgb/*.png).
    pub dataset: PathBuf,
    /// v4l2loopback output device to write into, e.g. /dev/video10.
    #[arg(long)]
    pub to: Option<PathBuf>,
    /// Speed factor; 1 plays at the recorded rate.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Start over at the end.
    #[arg(long = "loop")]
    pub looping: bool,
    /// Configuration file (for the iceoryx2 settings when publishing).
    #[arg(long, default_value = "/etc/star/star.toml")]
    pub config: PathBuf,
}

/// Runs the replay.
pub fn run(args: &ReplayArgs) -> Result<()> {
    anyhow::ensure!(
        crate::camera::replay_speed_is_sane(args.speed),
        "--speed must be within {}..={}, found {:?}",
        crate::camera::MIN_REPLAY_SPEED,
        crate::camera::MAX_REPLAY_SPEED,
        args.speed
    );
    match &args.to {
        Some(device) => to_loopback(args, device),
        None => super::camera::run(&super::camera::CameraArgs {
            config: args.config.clone(),
            source: Some(SourceUri::Replay(args.dataset.clone()).to_string()),
            frames: None,
            speed: Some(args.speed),
            looping: args.looping,
        }),
    }
}

#[cfg(feature = "v4l2")]
fn to_loopback(args: &ReplayArgs, device: &std::path::Path) -> Result<()> {
    use crate::camera::loopback::LoopbackWriter;
    use crate::camera::{CameraError, FrameSource, SourceSettings};
    use crate::ipc::{Frame, FrameSlot};

    crate::service::signals::install_shutdown_handler()?;
    let settings = SourceSettings {
        replay_speed: args.speed,
        replay_loop: args.looping,
        ..SourceSettings::default()
    };
    let mut source = ReplaySource::open(&args.dataset, &settings)
        .with_context(|| format!("dataset {}", args.dataset.display()))?;
    tracing::info!(source = %source.describe(), device = %device.display(), "virtual camera started");
    let progress = indicatif::ProgressBar::new(if args.looping { 0 } else { source.len() as u64 });
    let mut frame = Frame::boxed_zeroed();
    let mut writer: Option<LoopbackWriter> = None;
    loop {
        match source.next_frame(&mut FrameSlot::from_frame(&mut frame)) {
            Ok(()) => {}
            Err(CameraError::EndOfStream | CameraError::Stopped) => break,
            Err(e) => return Err(e).context("replay"),
        }
        let view = frame.view().context("replayed frame")?;
        if writer.is_none() {
            let fps = 30.0 * args.speed;
            writer = Some(
                LoopbackWriter::open(device, view.header.width, view.header.height, fps)
                    .with_context(|| format!("virtual camera {}", device.display()))?,
            );
        }
        if let Some(w) = writer.as_mut() {
            w.write_frame(&view).context("writing frame")?;
        }
        progress.inc(1);
    }
    progress.finish();
    let written = writer.map(|w| w.frames_written()).unwrap_or(0);
    tracing::info!(frames = written, "virtual camera finished");
    Ok(())
}

#[cfg(not(feature = "v4l2"))]
fn to_loopback(_args: &ReplayArgs, _device: &std::path::Path) -> Result<()> {
    anyhow::bail!("--to needs the `v4l2` cargo feature, which this binary was built without")
}
