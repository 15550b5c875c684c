//! V4L2 capture source (`v4l2:/dev/videoN`) through the `v4l` crate.
//!
//! Negotiates the configured size and rate in the first format the device
//! offers out of GREY/Y8, YUYV and MJPG, streams with N mmap buffers, and
//! converts each buffer to packed gray in the frame slot. The capture time is
//! the kernel's buffer timestamp when the driver marks it monotonic, else the
//! dequeue time. I/O errors (unplugged camera) surface as
//! [`CameraError::Disconnected`] so the publish loop reconnects.

use std::path::{Path, PathBuf};
use std::time::Duration;

use v4l::buffer::{Flags, Type};
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::CaptureStream;
use v4l::video::capture::Parameters;
use v4l::video::Capture;
use v4l::{Device, Format, FourCC};

use super::convert::{gray_from_grey, gray_from_jpeg, gray_from_yuyv};
use super::{CameraError, FrameSource, SourceSettings};
use crate::clock::monotonic_now_ns;
use crate::ipc::{FrameHeader, FrameSlot, FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};

/// Pixel formats read from V4L2, in order of preference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureFormat {
    /// 8-bit gray (`GREY`, also `Y800`/`Y8  `).
    Grey,
    /// Packed YUV 4:2:2; the Y bytes are taken.
    Yuyv,
    /// Motion JPEG; decoded to luma.
    Mjpg,
}

impl CaptureFormat {
    /// Maps a FourCC to a supported format.
    pub fn from_fourcc(code: &[u8; 4]) -> Option<Self> {
        match code {
            b"GREY" | b"Y800" | b"Y8  " => Some(Self::Grey),
            b"YUYV" => Some(Self::Yuyv),
            b"MJPG" => Some(Self::Mjpg),
            _ => None,
        }
    }

    fn fourcc(self) -> FourCC {
        match self {
            Self::Grey => FourCC::new(b"GREY"),
            Self::Yuyv => FourCC::new(b"YUYV"),
            Self::Mjpg => FourCC::new(b"MJPG"),
        }
    }
}

/// Converts a kernel buffer timestamp to CLOCK_MONOTONIC ns when the driver
/// says it is monotonic; otherwise returns `None`.
pub fn kernel_timestamp_ns(flags: Flags, sec: i64, usec: i64) -> Option<u64> {
    let kind = flags & Flags::TIMESTAMP_MASK;
    if kind == Flags::TIMESTAMP_MONOTONIC && sec >= 0 && usec >= 0 && (sec, usec) != (0, 0) {
        Some(sec as u64 * 1_000_000_000 + usec as u64 * 1_000)
    } else {
        None
    }
}

/// A streaming V4L2 capture device.
pub struct V4l2Source {
    path: PathBuf,
    // Field order matters: the stream unmaps its buffers before the device closes.
    stream: MmapStream<'static>,
    _device: Device,
    format: CaptureFormat,
    width: u32,
    height: u32,
    stride: u32,
    fps: f64,
    timeout_ms: u64,
}

fn open_err(path: &Path, what: &str, e: std::io::Error) -> CameraError {
    CameraError::Open {
        device: path.display().to_string(),
        reason: format!("{what}: {e}"),
    }
}

impl V4l2Source {
    /// Opens `path`, negotiates format, size and rate, and maps the buffers.
    pub fn open(path: &Path, settings: &SourceSettings) -> Result<Self, CameraError> {
        let device = Device::with_path(path).map_err(|e| open_err(path, "open", e))?;
        let offered = device
            .enum_formats()
            .map_err(|e| open_err(path, "VIDIOC_ENUM_FMT", e))?;
        let format = [
            CaptureFormat::Grey,
            CaptureFormat::Yuyv,
            CaptureFormat::Mjpg,
        ]
        .into_iter()
        .find(|want| {
            offered
                .iter()
                .any(|d| CaptureFormat::from_fourcc(&d.fourcc.repr) == Some(*want))
        })
        .ok_or_else(|| CameraError::Unsupported {
            device: path.display().to_string(),
            reason: format!(
                "offers {:?}, none of GREY/Y8, YUYV, MJPG",
                offered
                    .iter()
                    .map(|d| d.fourcc.to_string())
                    .collect::<Vec<_>>()
            ),
        })?;
        let requested = Format::new(settings.width, settings.height, format.fourcc());
        let actual = device
            .set_format(&requested)
            .map_err(|e| open_err(path, "VIDIOC_S_FMT", e))?;
        if CaptureFormat::from_fourcc(&actual.fourcc.repr) != Some(format) {
            return Err(CameraError::Unsupported {
                device: path.display().to_string(),
                reason: format!(
                    "asked for {}, driver chose {}",
                    format.fourcc(),
                    actual.fourcc
                ),
            });
        }
        if actual.width > FRAME_MAX_WIDTH || actual.height > FRAME_MAX_HEIGHT {
            return Err(CameraError::Unsupported {
                device: path.display().to_string(),
                reason: format!(
                    "driver chose {}x{}, frames hold at most {FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT}",
                    actual.width, actual.height
                ),
            });
        }
        if (actual.width, actual.height) != (settings.width, settings.height) {
            tracing::warn!(
                device = %path.display(),
                requested = %format!("{}x{}", settings.width, settings.height),
                actual = %format!("{}x{}", actual.width, actual.height),
                "camera does not offer the configured size; check the calibration"
            );
        }
        let fps = if settings.fps.is_finite() && settings.fps >= 1.0 {
            match device.set_params(&Parameters::with_fps(settings.fps.round() as u32)) {
                Ok(p) if p.interval.numerator > 0 => {
                    f64::from(p.interval.denominator) / f64::from(p.interval.numerator)
                }
                Ok(_) => settings.fps,
                Err(e) => {
                    tracing::warn!(device = %path.display(), error = %e, "cannot set frame rate");
                    settings.fps
                }
            }
        } else {
            settings.fps
        };
        let mut stream =
            MmapStream::with_buffers(&device, Type::VideoCapture, settings.buffers.max(2))
                .map_err(|e| open_err(path, "VIDIOC_REQBUFS/mmap", e))?;
        stream.set_timeout(Duration::from_millis(settings.frame_timeout_ms.max(1)));
        let stride = if format == CaptureFormat::Mjpg {
            actual.width
        } else {
            actual.stride
        };
        Ok(Self {
            path: path.to_owned(),
            stream,
            _device: device,
            format,
            width: actual.width,
            height: actual.height,
            stride,
            fps,
            timeout_ms: settings.frame_timeout_ms,
        })
    }
}

impl FrameSource for V4l2Source {
    fn describe(&self) -> String {
        format!(
            "V4L2 {} {}x{} {:?} at {:.1} Hz",
            self.path.display(),
            self.width,
            self.height,
            self.format,
            self.fps
        )
    }

    fn next_frame(&mut self, slot: &mut FrameSlot<'_>) -> Result<(), CameraError> {
        let (buf, meta) = match CaptureStream::next(&mut self.stream) {
            Ok(x) => x,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                return Err(CameraError::Timeout {
                    device: self.path.display().to_string(),
                    waited_ms: self.timeout_ms,
                })
            }
            Err(e) => {
                return Err(CameraError::Disconnected {
                    device: self.path.display().to_string(),
                    reason: e.to_string(),
                })
            }
        };
        let dequeued_ns = monotonic_now_ns();
        let bad = |reason: String| CameraError::BadFrame {
            device: self.path.display().to_string(),
            reason,
        };
        if meta.flags.contains(Flags::ERROR) {
            return Err(bad("driver flagged the buffer as corrupt".into()));
        }
        let used = (meta.bytesused as usize).min(buf.len());
        let data = &buf[..used];
        let (w, h, stride) = (
            self.width as usize,
            self.height as usize,
            self.stride as usize,
        );
        let result = match self.format {
            CaptureFormat::Grey => gray_from_grey(data, stride, w, h, &mut slot.pixels[..]),
            CaptureFormat::Yuyv => gray_from_yuyv(data, stride, w, h, &mut slot.pixels[..]),
            CaptureFormat::Mjpg => gray_from_jpeg(data, w, h, &mut slot.pixels[..]),
        };
        result.map_err(|e| bad(e.to_string()))?;
        *slot.header = FrameHeader::gray8(0, self.width, self.height);
        // time_t is i32 on 32-bit targets, i64 here.
        #[allow(clippy::useless_conversion)]
        let kernel_ns = kernel_timestamp_ns(
            meta.flags,
            i64::from(meta.timestamp.sec),
            i64::from(meta.timestamp.usec),
        );
        slot.header.capture_ns = kernel_ns.unwrap_or(dequeued_ns);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_map_from_fourcc() {
        assert_eq!(
            CaptureFormat::from_fourcc(b"GREY"),
            Some(CaptureFormat::Grey)
        );
        assert_eq!(
            CaptureFormat::from_fourcc(b"Y800"),
            Some(CaptureFormat::Grey)
        );
        assert_eq!(
            CaptureFormat::from_fourcc(b"YUYV"),
            Some(CaptureFormat::Yuyv)
        );
        assert_eq!(
            CaptureFormat::from_fourcc(b"MJPG"),
            Some(CaptureFormat::Mjpg)
        );
        assert_eq!(CaptureFormat::from_fourcc(b"RGB3"), None);
    }

    #[test]
    fn kernel_timestamp_used_only_when_monotonic() {
        let mono = Flags::TIMESTAMP_MONOTONIC;
        assert_eq!(kernel_timestamp_ns(mono, 2, 500), Some(2_000_500_000));
        assert_eq!(kernel_timestamp_ns(Flags::TIMESTAMP_COPY, 2, 500), None);
        assert_eq!(kernel_timestamp_ns(Flags::from(0), 2, 500), None);
        assert_eq!(kernel_timestamp_ns(mono, 0, 0), None);
    }

    #[test]
    fn missing_device_is_a_retryable_open_error() {
        let err = match V4l2Source::open(
            Path::new("/dev/video-star-missing"),
            &SourceSettings::default(),
        ) {
            Err(e) => e,
            Ok(_) => panic!("no such device"),
        };
        assert_eq!(err.action(), super::super::ErrorAction::Reconnect);
        assert!(err.to_string().contains("/dev/video-star-missing"), "{err}");
    }
}
