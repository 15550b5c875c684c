//! GenICam camera source (`aravis:ID`) through the `aravis` crate
//! (libaravis 0.8).
//!
//! Opens the camera by id (empty: the first one; `fake`: Aravis's built-in
//! fake camera, enabled through `arv_enable_interface("Fake")`), sets Mono8,
//! the configured region, frame rate, exposure and gain, and streams into a
//! pool of buffers allocated once at open. Each popped buffer is copied into
//! the frame slot and pushed back. The capture time is the buffer's host
//! timestamp converted to CLOCK_MONOTONIC.

use aravis::prelude::*;
use aravis::{AcquisitionMode, Auto, Buffer, BufferStatus, Camera, PixelFormat, Stream};

use super::convert::gray_from_grey;
use super::{CameraError, FrameSource, SourceSettings};
use crate::clock::realtime_to_monotonic_ns;
use crate::ipc::{FrameHeader, FrameSlot, FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};

/// Id that selects Aravis's in-process fake camera.
pub const FAKE_CAMERA_ID: &str = "fake";

/// Enables Aravis's "Fake" interface so the fake camera is listed.
pub fn enable_fake_interface() {
    // SAFETY: a static NUL-terminated string; the call only flips a flag in
    // Aravis's interface table.
    unsafe { aravis_sys::arv_enable_interface(c"Fake".as_ptr()) };
}

/// Ids of the cameras Aravis sees now.
pub fn list_cameras() -> Vec<String> {
    // SAFETY: Aravis's device list functions are safe to call at any time
    // from one thread; the crate wraps them unsafely only for that reason.
    unsafe { aravis::get_device_list() }
        .into_iter()
        .map(|d| d.id.to_string_lossy().into_owned())
        .collect()
}

/// A streaming GenICam camera.
pub struct AravisSource {
    id: String,
    camera: Camera,
    stream: Stream,
    width: u32,
    height: u32,
    fps: f64,
    exposure_us: f32,
    gain_db: f32,
    timeout_ms: u64,
}

fn glib_err(id: &str, what: &str, e: aravis::glib::Error) -> CameraError {
    CameraError::Open {
        device: format!("aravis:{id}"),
        reason: format!("{what}: {e}"),
    }
}

impl AravisSource {
    /// Opens camera `id` and starts acquisition with `settings`.
    pub fn open(id: &str, settings: &SourceSettings) -> Result<Self, CameraError> {
        let wanted = if id == FAKE_CAMERA_ID {
            enable_fake_interface();
            list_cameras()
                .into_iter()
                .find(|c| c.to_ascii_lowercase().contains("fake"))
                .ok_or_else(|| CameraError::Open {
                    device: format!("aravis:{id}"),
                    reason: "fake interface enabled but no fake camera listed".into(),
                })
                .map(Some)?
        } else if id.is_empty() {
            None
        } else {
            Some(id.to_string())
        };
        let camera = Camera::new(wanted.as_deref()).map_err(|e| glib_err(id, "open", e))?;
        let name = wanted.unwrap_or_else(|| {
            camera
                .device_id()
                .map(|s| s.to_string())
                .unwrap_or_else(|_| "first camera".into())
        });
        camera
            .set_pixel_format(PixelFormat::MONO_8)
            .map_err(|e| CameraError::Unsupported {
                device: format!("aravis:{name}"),
                reason: format!("cannot set Mono8: {e}"),
            })?;
        if settings.width > FRAME_MAX_WIDTH || settings.height > FRAME_MAX_HEIGHT {
            return Err(CameraError::Unsupported {
                device: format!("aravis:{name}"),
                reason: format!(
                    "{}x{} exceeds the {FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT} frame capacity",
                    settings.width, settings.height
                ),
            });
        }
        camera
            .set_region(0, 0, settings.width as i32, settings.height as i32)
            .map_err(|e| glib_err(&name, "set region", e))?;
        let (_, _, width, height) = camera.region().map_err(|e| glib_err(&name, "region", e))?;
        if width <= 0
            || height <= 0
            || width as u32 > FRAME_MAX_WIDTH
            || height as u32 > FRAME_MAX_HEIGHT
        {
            return Err(CameraError::Unsupported {
                device: format!("aravis:{name}"),
                reason: format!("camera region is {width}x{height}"),
            });
        }
        let _ = camera.set_acquisition_mode(AcquisitionMode::Continuous);
        if camera.is_frame_rate_available().unwrap_or(false) {
            camera
                .set_frame_rate(settings.fps)
                .map_err(|e| glib_err(&name, "set frame rate", e))?;
        }
        match settings.exposure_us {
            Some(us) => camera
                .set_exposure_time(us)
                .map_err(|e| glib_err(&name, "set exposure", e))?,
            None => {
                if camera.is_exposure_auto_available().unwrap_or(false) {
                    let _ = camera.set_exposure_time_auto(Auto::Continuous);
                }
            }
        }
        match settings.gain_db {
            Some(db) => camera
                .set_gain(db)
                .map_err(|e| glib_err(&name, "set gain", e))?,
            None => {
                if camera.is_gain_auto_available().unwrap_or(false) {
                    let _ = camera.set_gain_auto(Auto::Continuous);
                }
            }
        }
        let fps = camera.frame_rate().unwrap_or(settings.fps);
        let exposure_us = camera.exposure_time().unwrap_or(0.0) as f32;
        let gain_db = camera.gain().unwrap_or(0.0) as f32;
        let payload = camera
            .payload()
            .map_err(|e| glib_err(&name, "payload size", e))?;
        let stream = camera
            .create_stream()
            .map_err(|e| glib_err(&name, "create stream", e))?;
        for _ in 0..settings.buffers.max(2) {
            stream.push_buffer(Buffer::new_allocate(payload as usize));
        }
        camera
            .start_acquisition()
            .map_err(|e| glib_err(&name, "start acquisition", e))?;
        Ok(Self {
            id: name,
            camera,
            stream,
            width: width as u32,
            height: height as u32,
            fps,
            exposure_us,
            gain_db,
            timeout_ms: settings.frame_timeout_ms,
        })
    }
}

impl Drop for AravisSource {
    fn drop(&mut self) {
        let _ = self.camera.stop_acquisition();
    }
}

impl FrameSource for AravisSource {
    fn describe(&self) -> String {
        format!(
            "Aravis {} {}x{} Mono8 at {:.1} Hz, exposure {:.0} us, gain {:.1} dB",
            self.id, self.width, self.height, self.fps, self.exposure_us, self.gain_db
        )
    }

    fn next_frame(&mut self, slot: &mut FrameSlot<'_>) -> Result<(), CameraError> {
        let Some(buffer) = self.stream.timeout_pop_buffer(self.timeout_ms * 1000) else {
            return Err(CameraError::Timeout {
                device: format!("aravis:{}", self.id),
                waited_ms: self.timeout_ms,
            });
        };
        let result = self.copy_buffer(&buffer, slot);
        self.stream.push_buffer(buffer);
        result
    }
}

impl AravisSource {
    fn copy_buffer(&self, buffer: &Buffer, slot: &mut FrameSlot<'_>) -> Result<(), CameraError> {
        let bad = |reason: String| CameraError::BadFrame {
            device: format!("aravis:{}", self.id),
            reason,
        };
        let status = buffer.status();
        if status != BufferStatus::Success {
            return Err(bad(format!("buffer status {status:?}")));
        }
        let format = buffer.image_pixel_format();
        if format != PixelFormat::MONO_8 {
            return Err(bad(format!("pixel format {format:?}, expected Mono8")));
        }
        let (w, h) = (buffer.image_width(), buffer.image_height());
        if w <= 0 || h <= 0 || w as u32 > FRAME_MAX_WIDTH || h as u32 > FRAME_MAX_HEIGHT {
            return Err(bad(format!("image size {w}x{h}")));
        }
        let (ptr, len) = buffer.data();
        if ptr.is_null() {
            return Err(bad("buffer has no data".into()));
        }
        // SAFETY: Aravis owns `len` readable bytes at `ptr` while we hold the buffer.
        let data = unsafe { std::slice::from_raw_parts(ptr as *const u8, len) };
        let (w, h) = (w as usize, h as usize);
        gray_from_grey(data, w, w, h, &mut slot.pixels[..]).map_err(|e| bad(e.to_string()))?;
        *slot.header = FrameHeader::gray8(0, w as u32, h as u32);
        let host_ns = buffer.system_timestamp();
        slot.header.capture_ns = if host_ns > 0 {
            realtime_to_monotonic_ns(host_ns)
        } else {
            crate::clock::monotonic_now_ns()
        };
        slot.header.exposure_us = self.exposure_us;
        slot.header.gain_db = self.gain_db;
        Ok(())
    }
}
