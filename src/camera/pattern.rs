//! A moving test pattern source (`pattern:WxH`), paced at the configured
//! rate. Used by tests and demos where no camera exists; it exercises the
//! same publish path as a real camera.

use std::time::Duration;

use super::{CameraError, FrameSource};
use crate::clock::monotonic_now_ns;
use crate::ipc::{FrameHeader, FrameSlot, FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH};

/// Diagonal gradient that shifts by one pixel per frame.
pub struct PatternSource {
    width: u32,
    height: u32,
    period_ns: u64,
    next_due_ns: u64,
    frame: u64,
}

impl PatternSource {
    /// A `width` x `height` pattern at `fps` frames per second.
    pub fn new(width: u32, height: u32, fps: f64) -> Result<Self, CameraError> {
        if width > FRAME_MAX_WIDTH || height > FRAME_MAX_HEIGHT {
            return Err(CameraError::Unsupported {
                device: format!("pattern:{width}x{height}"),
                reason: format!(
                    "larger than the {FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT} frame capacity"
                ),
            });
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(CameraError::Unsupported {
                device: format!("pattern:{width}x{height}"),
                reason: format!("frame rate must be positive, found {fps}"),
            });
        }
        Ok(Self {
            width,
            height,
            period_ns: (1e9 / fps) as u64,
            next_due_ns: 0,
            frame: 0,
        })
    }

    /// Expected pixel value at `(x, y)` of frame number `frame` (for tests).
    pub fn value(frame: u64, x: u32, y: u32) -> u8 {
        (u64::from(x) + u64::from(y) + frame) as u8
    }
}

impl FrameSource for PatternSource {
    fn describe(&self) -> String {
        format!(
            "test pattern {}x{} GREY at {:.1} Hz",
            self.width,
            self.height,
            1e9 / self.period_ns as f64
        )
    }

    fn next_frame(&mut self, slot: &mut FrameSlot<'_>) -> Result<(), CameraError> {
        let now = monotonic_now_ns();
        if self.next_due_ns == 0 {
            self.next_due_ns = now;
        }
        if self.next_due_ns > now {
            std::thread::sleep(Duration::from_nanos(self.next_due_ns - now));
        }
        self.next_due_ns += self.period_ns;
        let (w, h) = (self.width as usize, self.height as usize);
        for (y, row) in slot.pixels[..w * h].chunks_exact_mut(w).enumerate() {
            for (x, p) in row.iter_mut().enumerate() {
                *p = Self::value(self.frame, x as u32, y as u32);
            }
        }
        *slot.header = FrameHeader::gray8(0, self.width, self.height);
        slot.header.capture_ns = monotonic_now_ns();
        self.frame += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ipc::Frame;

    #[test]
    fn pattern_moves_and_stamps_monotonic_time() {
        let mut source = PatternSource::new(8, 4, 1000.0).expect("valid");
        let mut frame = Frame::boxed_zeroed();
        let mut slot = FrameSlot::from_frame(&mut frame);
        source.next_frame(&mut slot).expect("frame 0");
        let t0 = slot.header.capture_ns;
        source.next_frame(&mut slot).expect("frame 1");
        assert!(slot.header.capture_ns >= t0);
        let view = frame.view().expect("valid header");
        assert_eq!(view.row(2).expect("row")[3], PatternSource::value(1, 3, 2));
    }

    #[test]
    fn rejects_oversized_and_bad_rate() {
        assert!(PatternSource::new(FRAME_MAX_WIDTH + 1, 4, 30.0).is_err());
        assert!(PatternSource::new(8, 4, 0.0).is_err());
    }
}
