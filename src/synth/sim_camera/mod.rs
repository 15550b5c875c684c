//! The camera of a simulated vehicle (`sim:` source): closed-loop flight on
//! vision in ArduPilot SITL.
//!
//! Owns [`SimCamera`] (the scene, loaded once) and the [`FrameSource`] it
//! opens. Takes a [`SimUri`] (the simulator's MAVLink connection, the
//! `star synth` dataset whose scene the vehicle flies in, the geodetic
//! origin), the camera intrinsics, the frame rate and the two transforms of
//! `[mavlink]`; gives out 8-bit frames of the scene's truth mesh (no map
//! holes, with the occluders) seen from the vehicle's true pose, through the
//! preset's sensor model (motion blur, lens distortion, drift, vignetting,
//! noise: [`super::camera_model`]), stamped with their capture time.
//!
//! The pose: SITL's SIM_STATE gives the true body pose (`ned_from_body`,
//! [`truth`]), and the camera is at
//! `world_from_camera = inverse(ned_from_world) * ned_from_body *
//! body_from_camera`, the inverse of the conversion the MAVLink output makes,
//! so a perfect tracker sends back exactly the simulator's truth.
//!
//! Timing, and the latency it leaves: frames are captured on a fixed grid
//! of CLOCK_MONOTONIC instants, `1 / fps` apart (a late frame skips grid
//! instants, never bunches). At each instant the newest SIM_STATE (asked
//! for at 100 Hz, [`reader`]) is extrapolated from its arrival time to the
//! instant (constant velocity and body rate, over 10 ms at most while
//! SITL streams) and rendered; the frame's `capture_ns` is that instant. The
//! one latency not corrected is SIM_STATE's way from SITL's physics step
//! to our socket (SITL's scheduling plus local TCP: under a millisecond on
//! an idle machine, more when it is loaded): the picture shows the vehicle
//! that much earlier than its stamp says. Rendering happens after the
//! capture instant, as a real camera's exposure and readout do, and is part
//! of the capture-to-autopilot delay the autopilot must be told about
//! (`VISO_DELAY_MS`).
//!
//! The scene is rebuilt from the dataset's `synth.toml` (preset, seed,
//! scene seed), exactly as `star synth` built it, and checked against the
//! dataset's `map/map.obj` ([`scene`]). The camera's intrinsics are the
//! config's (`[camera.intrinsics]`, with its distortion), not the preset's,
//! so a smaller camera can stand in where CPU is short. A scanned dataset
//! (`--scanned`) is refused: its map is in the scanner's frame and its
//! flight light is not modelled here.

pub mod reader;
pub mod scene;
pub mod truth;

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use crate::camera::{CameraError, FrameSource, GeoPoint, SimUri};
use crate::clock::monotonic_now_ns;
use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::ImageU8;
use crate::ipc::{FrameHeader, FrameSlot, FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};
use crate::mavlink_io::link::Link;
use crate::mavlink_io::LinkAddress;
use crate::service::signals::sleep_unless_shutdown;

use super::camera_model::{SyntheticCamera, SyntheticCameraError};
use reader::{FeedError, TruthFeed};
pub use scene::SimScene;

/// A state older than this at a capture instant is not extrapolated: the
/// camera waits for a fresh one (SITL paused or stopped streaming).
pub const MAX_STATE_AGE_NS: u64 = 100_000_000;

/// Why a sim camera cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// No scene folder given and none derivable from `map.mesh`.
    #[error("sim camera: no scene: give `?scene=DATASET_DIR` or set map.mesh to a `star synth` dataset's map/map.obj (found {mesh})")]
    NoScene {
        /// The configured map mesh.
        mesh: PathBuf,
    },
    /// `synth.toml` cannot be read or does not describe a scene we can rebuild.
    #[error("sim camera scene {path}: {reason}")]
    Scene {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The camera (lens warp, renderer) cannot be built.
    #[error("sim camera: {0}")]
    Camera(#[from] SyntheticCameraError),
    /// The intrinsics or the rate are out of range.
    #[error("sim camera: {0}")]
    Settings(String),
}

/// Everything a sim camera needs besides the scene.
#[derive(Debug, Clone)]
pub struct SimSettings {
    /// The camera (intrinsics and distortion), `[camera.intrinsics]`.
    pub camera: PinholeCamera,
    /// Frame rate, Hz (`camera.fps`).
    pub fps: f64,
    /// `[mavlink.ned_from_world]`.
    pub ned_from_world: Pose,
    /// `[mavlink.body_from_camera]`.
    pub body_from_camera: Pose,
    /// How long to wait for the simulator before reconnecting, ms.
    pub frame_timeout_ms: u64,
}

/// A sim camera: the scene, loaded once, and what each open needs.
pub struct SimCamera {
    uri: SimUri,
    address: LinkAddress,
    scene: SimScene,
    settings: SimSettings,
    /// Kept across reconnects: the local frame must not move.
    origin: Arc<OnceLock<GeoPoint>>,
}

impl SimCamera {
    /// Loads the scene of `uri` (or the dataset holding `map_mesh`) and
    /// checks the settings.
    pub fn new(uri: &SimUri, map_mesh: &Path, settings: SimSettings) -> Result<Self, SimError> {
        let address =
            LinkAddress::parse(&uri.link).map_err(|e| SimError::Settings(e.to_string()))?;
        let (w, h) = (settings.camera.width, settings.camera.height);
        if w > FRAME_MAX_WIDTH || h > FRAME_MAX_HEIGHT {
            return Err(SimError::Settings(format!(
                "camera {w}x{h} is larger than the {FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT} frame capacity"
            )));
        }
        if !(settings.fps.is_finite() && settings.fps > 0.0 && settings.fps <= 1000.0) {
            return Err(SimError::Settings(format!(
                "frame rate must be within 0..=1000 Hz, found {}",
                settings.fps
            )));
        }
        let dir = match &uri.scene {
            Some(dir) => dir.clone(),
            None => SimScene::dir_of_map(map_mesh).ok_or_else(|| SimError::NoScene {
                mesh: map_mesh.to_path_buf(),
            })?,
        };
        let scene = SimScene::load(&dir)?;
        let origin = Arc::new(OnceLock::new());
        if let Some(o) = uri.origin {
            let _ = origin.set(o);
        }
        // Fail now, not at the first open, on a camera the warp cannot take.
        SyntheticCamera::new(
            scene.image_mesh.clone(),
            &settings.camera,
            scene.photometric,
            scene.blur,
            scene.seed,
        )?;
        Ok(Self {
            uri: uri.clone(),
            address,
            scene,
            settings,
            origin,
        })
    }

    /// The scene.
    pub fn scene(&self) -> &SimScene {
        &self.scene
    }

    /// Connects to the simulator and returns the source.
    pub fn open(&self) -> Result<Box<dyn FrameSource>, CameraError> {
        let device = self.uri.to_string();
        let link = Link::open(&self.address).map_err(|e| CameraError::Open {
            device: device.clone(),
            reason: e.to_string(),
        })?;
        let camera = SyntheticCamera::new(
            self.scene.image_mesh.clone(),
            &self.settings.camera,
            self.scene.photometric,
            self.scene.blur,
            self.scene.seed,
        )
        .map_err(|e| CameraError::Unsupported {
            device: device.clone(),
            reason: e.to_string(),
        })?;
        let feed = TruthFeed::start(link, self.origin.clone()).map_err(|e| CameraError::Open {
            device: device.clone(),
            reason: format!("cannot start the simulator reader thread: {e}"),
        })?;
        Ok(Box::new(SimSource {
            device,
            preset: self.scene.preset,
            feed,
            camera,
            world_from_ned: self.settings.ned_from_world.inverse(),
            body_from_camera: self.settings.body_from_camera,
            width: self.settings.camera.width,
            height: self.settings.camera.height,
            period_ns: (1e9 / self.settings.fps) as u64,
            timeout: Duration::from_millis(self.settings.frame_timeout_ms),
            start_ns: 0,
            next_due_ns: 0,
            frame_index: 0,
            late_frames: 0,
            image: ImageU8::new(
                self.settings.camera.width as usize,
                self.settings.camera.height as usize,
                0,
            ),
        }))
    }
}

/// An open sim camera.
struct SimSource {
    device: String,
    preset: &'static str,
    feed: TruthFeed,
    camera: SyntheticCamera,
    world_from_ned: Pose,
    body_from_camera: Pose,
    width: u32,
    height: u32,
    period_ns: u64,
    timeout: Duration,
    /// The first capture instant (the sensor model's time zero).
    start_ns: u64,
    next_due_ns: u64,
    frame_index: u64,
    /// Grid instants skipped because a frame took longer than a period.
    late_frames: u64,
    image: ImageU8,
}

impl SimSource {
    fn feed_error(&self, e: FeedError) -> CameraError {
        match e {
            FeedError::Timeout => CameraError::Timeout {
                device: self.device.clone(),
                waited_ms: self.timeout.as_millis() as u64,
            },
            FeedError::Broken(reason) => CameraError::Disconnected {
                device: self.device.clone(),
                reason,
            },
            FeedError::Stopped => CameraError::Stopped,
        }
    }
}

impl FrameSource for SimSource {
    fn describe(&self) -> String {
        format!(
            "sim camera {}x{} GREY at {:.1} Hz, `{}` scene, truth from {}",
            self.width,
            self.height,
            1e9 / self.period_ns as f64,
            self.preset,
            self.device
        )
    }

    fn next_frame(&mut self, slot: &mut FrameSlot<'_>) -> Result<(), CameraError> {
        if self.next_due_ns == 0 {
            // The first frame waits for the first state.
            let first = self
                .feed
                .wait_newer(0, self.timeout)
                .map_err(|e| self.feed_error(e))?;
            self.start_ns = first.arrival_ns.max(monotonic_now_ns());
            self.next_due_ns = self.start_ns;
        }
        let now = monotonic_now_ns();
        if self.next_due_ns + self.period_ns <= now {
            // Late: skip to the next grid instant, never a burst.
            let skipped = (now - self.next_due_ns) / self.period_ns;
            self.late_frames += skipped;
            self.next_due_ns += (skipped + 1) * self.period_ns;
            tracing::debug!(skipped, late_frames = self.late_frames, "sim camera late");
        }
        let now = monotonic_now_ns();
        if self.next_due_ns > now
            && !sleep_unless_shutdown(Duration::from_nanos(self.next_due_ns - now))
        {
            return Err(CameraError::Stopped);
        }
        let mut capture_ns = self.next_due_ns;
        self.next_due_ns += self.period_ns;
        let newer_than = capture_ns.saturating_sub(MAX_STATE_AGE_NS);
        let sample = match self.feed.wait_newer(newer_than, Duration::ZERO) {
            Ok(sample) => sample,
            Err(FeedError::Timeout) => {
                tracing::warn!(
                    max_age_ms = MAX_STATE_AGE_NS / 1_000_000,
                    "sim camera: no fresh SIM_STATE; waiting"
                );
                let sample = self
                    .feed
                    .wait_newer(newer_than, self.timeout)
                    .map_err(|e| self.feed_error(e))?;
                // Start the grid again at the fresh state.
                capture_ns = sample.arrival_ns.max(capture_ns);
                self.next_due_ns = capture_ns + self.period_ns;
                sample
            }
            Err(e) => return Err(self.feed_error(e)),
        };
        let t_s = (capture_ns - self.start_ns) as f64 * 1e-9;
        let age_s = (capture_ns as f64 - sample.arrival_ns as f64) * 1e-9;
        let (world_from_ned, body_from_camera) = (self.world_from_ned, self.body_from_camera);
        let state = sample.state;
        self.camera
            .expose(
                |t| {
                    world_from_ned * state.ned_from_body_after(age_s + (t - t_s)) * body_from_camera
                },
                t_s,
                |_, _, _| {},
            )
            .map_err(|e| CameraError::BadFrame {
                device: self.device.clone(),
                reason: format!("render failed: {e}"),
            })?;
        self.camera
            .develop(None, self.frame_index, t_s, &mut self.image);
        let n = self.image.data().len();
        let Some(pixels) = slot.pixels.get_mut(..n) else {
            return Err(CameraError::Unsupported {
                device: self.device.clone(),
                reason: format!(
                    "a {}x{} frame does not fit the slot",
                    self.width, self.height
                ),
            });
        };
        pixels.copy_from_slice(self.image.data());
        *slot.header = FrameHeader::gray8(0, self.width, self.height);
        slot.header.capture_ns = capture_ns;
        if tracing::enabled!(tracing::Level::TRACE) {
            let pose = world_from_ned * state.ned_from_body_after(age_s) * body_from_camera;
            let (t, q) = (pose.translation.vector, pose.rotation);
            tracing::trace!(
                frame = self.frame_index,
                capture_ns,
                state_age_ms = age_s * 1e3,
                states = sample.count,
                world_from_camera = %format_args!(
                    "{} {} {} {} {} {} {}", t.x, t.y, t.z, q.i, q.j, q.k, q.w
                ),
                "sim frame"
            );
        }
        self.frame_index += 1;
        Ok(())
    }
}

impl Drop for SimSource {
    fn drop(&mut self) {
        tracing::info!(
            frames = self.frame_index,
            late_frames = self.late_frames,
            rejected_states = self.feed.rejected(),
            "sim camera closed"
        );
    }
}

#[cfg(test)]
mod tests;
