//! `--rerun save:FILE.rrd|connect:ADDR` and `--rerun-every N`: the live
//! view's options, shared by `star track`, `star run` and `star localize`.
//! Accepted by every build; a build without the cargo feature `rerun`
//! refuses them at start, saying how to get it.

use anyhow::Result;

use crate::output::rerun_target::RerunTarget;

/// The live-view options.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RerunArgs {
    /// Log what the tracker sees to Rerun: `save:FILE.rrd` (open it with
    /// the Rerun viewer) or `connect:HOST[:PORT]` (a running viewer, port
    /// 9876 by default). Needs a build with `--features rerun`.
    #[arg(long, value_name = "save:FILE.rrd|connect:ADDR")]
    pub rerun: Option<String>,
    /// With --rerun: log the pictures (camera frame, keyframe render, warped
    /// frame, residual, the points by Huber weight) every Nth frame
    /// (default 5; 0: none). The scalars and the pose go every frame.
    #[arg(long, value_name = "N", requires = "rerun")]
    pub rerun_every: Option<u32>,
}

impl RerunArgs {
    /// The parsed target; an error for a malformed value, or for any value
    /// when the build has no `rerun` feature.
    pub fn target(&self) -> Result<Option<RerunTarget>> {
        let Some(text) = &self.rerun else {
            return Ok(None);
        };
        let target = RerunTarget::parse(text)?;
        if cfg!(not(feature = "rerun")) {
            anyhow::bail!(
                "--rerun {text}: this star was built without the `rerun` cargo feature; rebuild with `cargo build --release --features rerun`"
            );
        }
        Ok(Some(target))
    }

    /// Pictures every this many frames.
    pub fn every(&self) -> u32 {
        self.rerun_every.unwrap_or(5)
    }

    /// Starts the live view, when asked.
    #[cfg(feature = "rerun")]
    pub fn start(
        &self,
        camera: &crate::geometry::PinholeCamera,
        tracker: &crate::track::TrackerConfig,
        statics: impl FnOnce() -> Result<crate::output::rerun_log::RerunStatics>,
    ) -> Result<Option<crate::output::rerun_log::RerunSink>> {
        use anyhow::Context;
        let Some(target) = self.target()? else {
            return Ok(None);
        };
        let statics = statics()?;
        crate::output::rerun_log::RerunSink::start(&target, camera, tracker, self.every(), statics)
            .with_context(|| format!("--rerun {}", self.rerun.as_deref().unwrap_or("")))
            .map(Some)
    }
}

/// Prints what the live view logged.
#[cfg(feature = "rerun")]
pub fn print_rerun_summary(who: &str, s: &crate::output::rerun_log::RerunSummary) {
    println!(
        "{who}: Rerun rows {}  pictures {}  relocalization attempts {}  dropped rows {}  skipped pictures {}  refused log calls {}",
        s.rows, s.pictures, s.attempts, s.rows_dropped, s.pictures_dropped, s.log_errors
    );
}
