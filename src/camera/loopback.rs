//! Virtual-camera writer for hardware-in-the-loop tests: writes gray frames
//! into a v4l2loopback output device, which any V4L2 reader (including
//! `star camera --source v4l2:/dev/videoN`) then captures as a camera.
//!
//! Takes in validated frame views (from a [`FrameSource`](super::FrameSource)
//! such as replay); gives out GREY frames on the device, one `write()` per
//! frame. Pacing is the source's job.

use std::io::Write;
use std::path::{Path, PathBuf};

use v4l::capability::Flags as CapFlags;
use v4l::video::output::Parameters;
use v4l::video::Output;
use v4l::{Device, Format, FourCC};

use super::CameraError;
use crate::ipc::FrameView;

/// Name the v4l2loopback driver reports in `VIDIOC_QUERYCAP`.
pub const LOOPBACK_DRIVER: &str = "v4l2 loopback";

/// Whether `path` is a v4l2loopback device that accepts output.
pub fn is_loopback_output(path: &Path) -> bool {
    Device::with_path(path)
        .and_then(|d| d.query_caps())
        .map(|caps| {
            caps.driver == LOOPBACK_DRIVER && caps.capabilities.contains(CapFlags::VIDEO_OUTPUT)
        })
        .unwrap_or(false)
}

/// The first v4l2loopback output device among `/dev/video*`, if any.
pub fn find_loopback_device() -> Option<PathBuf> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir("/dev")
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("video"))
        })
        .collect();
    paths.sort();
    paths.into_iter().find(|p| is_loopback_output(p))
}

/// An open v4l2loopback output with a fixed GREY format.
pub struct LoopbackWriter {
    path: PathBuf,
    device: Device,
    width: u32,
    height: u32,
    /// Rows repacked here when a frame has stride padding (allocated once).
    packed: Vec<u8>,
    frames_written: u64,
}

impl LoopbackWriter {
    /// Opens `path` and sets a `width` x `height` GREY output at `fps`.
    pub fn open(path: &Path, width: u32, height: u32, fps: f64) -> Result<Self, CameraError> {
        let device_name = path.display().to_string();
        let device = Device::with_path(path).map_err(|e| CameraError::Open {
            device: device_name.clone(),
            reason: e.to_string(),
        })?;
        let caps = device.query_caps().map_err(|e| CameraError::Open {
            device: device_name.clone(),
            reason: format!("VIDIOC_QUERYCAP: {e}"),
        })?;
        if !caps.capabilities.contains(CapFlags::VIDEO_OUTPUT) {
            return Err(CameraError::Unsupported {
                device: device_name,
                reason: format!(
                    "driver `{}` offers no video output; expected a v4l2loopback device",
                    caps.driver
                ),
            });
        }
        let format = Output::set_format(&device, &Format::new(width, height, FourCC::new(b"GREY")))
            .map_err(|e| CameraError::Open {
                device: device_name.clone(),
                reason: format!("VIDIOC_S_FMT: {e}"),
            })?;
        if (format.width, format.height, &format.fourcc.repr) != (width, height, b"GREY") {
            return Err(CameraError::Unsupported {
                device: device_name,
                reason: format!(
                    "asked for {width}x{height} GREY, device took {}x{} {}",
                    format.width, format.height, format.fourcc
                ),
            });
        }
        if fps.is_finite() && fps >= 1.0 {
            // Informational for readers; v4l2loopback accepts any rate.
            let _ = Output::set_params(&device, &Parameters::with_fps(fps.round() as u32));
        }
        Ok(Self {
            path: path.to_owned(),
            device,
            width,
            height,
            packed: vec![0; (width * height) as usize],
            frames_written: 0,
        })
    }

    /// Writes one frame; its size must match the negotiated one.
    pub fn write_frame(&mut self, frame: &FrameView<'_>) -> Result<(), CameraError> {
        if (frame.header.width, frame.header.height) != (self.width, self.height) {
            return Err(CameraError::BadFrame {
                device: self.path.display().to_string(),
                reason: format!(
                    "frame is {}x{}, device is set to {}x{}",
                    frame.header.width, frame.header.height, self.width, self.height
                ),
            });
        }
        let w = self.width as usize;
        let bytes: &[u8] = if frame.header.stride == self.width {
            frame.pixels
        } else {
            for (y, out) in self.packed.chunks_exact_mut(w).enumerate() {
                if let Some(row) = frame.row(y) {
                    out.copy_from_slice(row);
                }
            }
            &self.packed
        };
        self.device
            .write_all(bytes)
            .map_err(|e| CameraError::Disconnected {
                device: self.path.display().to_string(),
                reason: format!("write: {e}"),
            })?;
        self.frames_written += 1;
        Ok(())
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.frames_written
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_loopback_paths_are_not_loopback() {
        assert!(!is_loopback_output(Path::new("/dev/null")));
        assert!(!is_loopback_output(Path::new("/dev/video-star-missing")));
        assert!(LoopbackWriter::open(Path::new("/dev/video-star-missing"), 8, 8, 30.0).is_err());
    }
}
