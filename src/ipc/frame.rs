//! The camera frame as it lies in shared memory: a fixed-size, `#[repr(C)]`
//! header followed by a fixed-capacity pixel array.
//!
//! Owns the wire layout ([`Frame`], [`FrameHeader`], [`PixelFormat`]), the
//! header validation that both sides apply ([`FrameHeader::validate`]), and the
//! borrowed views that readers use ([`FrameView`]). A `Frame` is never built
//! on the stack: the publisher writes into the loaned shared-memory sample
//! through [`FrameSlot`], and tests use [`Frame::boxed_zeroed`].

use iceoryx2::prelude::ZeroCopySend;

/// Widest frame the transport carries, pixels.
pub const FRAME_MAX_WIDTH: u32 = 2048;
/// Tallest frame the transport carries, pixels.
pub const FRAME_MAX_HEIGHT: u32 = 1536;
/// Size of the pixel array in every frame, bytes (8-bit gray at the maximum size).
pub const FRAME_CAPACITY_BYTES: usize = (FRAME_MAX_WIDTH * FRAME_MAX_HEIGHT) as usize;

/// Pixel layouts a frame may carry, stored as a V4L2-style FourCC in the header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit gray, one byte per pixel (`GREY`).
    Gray8,
}

impl PixelFormat {
    /// FourCC code stored in [`FrameHeader::pixel_format`].
    pub const fn fourcc(self) -> u32 {
        match self {
            PixelFormat::Gray8 => u32::from_le_bytes(*b"GREY"),
        }
    }

    /// The format for a FourCC code, `None` when unknown.
    pub fn from_fourcc(code: u32) -> Option<Self> {
        (code == PixelFormat::Gray8.fourcc()).then_some(PixelFormat::Gray8)
    }

    /// Bytes per pixel.
    pub const fn bytes_per_pixel(self) -> u32 {
        match self {
            PixelFormat::Gray8 => 1,
        }
    }
}

/// Sentinel for "no dataset timestamp" in [`FrameHeader::dataset_stamp_ns`].
pub const NO_DATASET_STAMP: i64 = i64::MIN;

/// Metadata that precedes the pixels. All fields are plain integers or
/// floats, so every bit pattern is a valid (if possibly inconsistent) header.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("star::FrameHeader")]
pub struct FrameHeader {
    /// Frame counter of the publishing camera session, starting at 0.
    pub sequence: u64,
    /// Capture time, CLOCK_MONOTONIC nanoseconds (from the driver's buffer
    /// timestamp when it has one; replay uses the publish time).
    pub capture_ns: u64,
    /// Timestamp of the frame in its dataset (replay), nanoseconds, or
    /// [`NO_DATASET_STAMP`] for live cameras.
    pub dataset_stamp_ns: i64,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Bytes from the start of one row to the next.
    pub stride: u32,
    /// FourCC of the [`PixelFormat`].
    pub pixel_format: u32,
    /// Exposure time, microseconds (0 when unknown).
    pub exposure_us: f32,
    /// Analog gain, dB (0 when unknown).
    pub gain_db: f32,
}

/// Why a frame header was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Width or height is zero.
    #[error("frame {sequence}: zero size {width}x{height}")]
    ZeroSize {
        /// Sequence number of the frame.
        sequence: u64,
        /// Width found.
        width: u32,
        /// Height found.
        height: u32,
    },
    /// The pixel format code is not one of [`PixelFormat`].
    #[error("frame {sequence}: unknown pixel format 0x{fourcc:08x}")]
    UnknownFormat {
        /// Sequence number of the frame.
        sequence: u64,
        /// FourCC found.
        fourcc: u32,
    },
    /// The stride is smaller than one row of pixels.
    #[error("frame {sequence}: stride {stride} < row size {row_bytes}")]
    StrideTooSmall {
        /// Sequence number of the frame.
        sequence: u64,
        /// Stride found.
        stride: u32,
        /// Bytes in one row at this width and format.
        row_bytes: u64,
    },
    /// `stride * height` exceeds the pixel capacity, or a side exceeds the maximum.
    #[error(
        "frame {sequence}: {width}x{height} stride {stride} needs {needed_bytes} bytes, capacity is {capacity_bytes} ({FRAME_MAX_WIDTH}x{FRAME_MAX_HEIGHT} max)"
    )]
    OverCapacity {
        /// Sequence number of the frame.
        sequence: u64,
        /// Width found.
        width: u32,
        /// Height found.
        height: u32,
        /// Stride found.
        stride: u32,
        /// Bytes the header claims.
        needed_bytes: u64,
        /// [`FRAME_CAPACITY_BYTES`].
        capacity_bytes: u64,
    },
}

impl FrameHeader {
    /// A header for a tightly packed gray frame; times and exposure are zero.
    pub fn gray8(sequence: u64, width: u32, height: u32) -> Self {
        Self {
            sequence,
            capture_ns: 0,
            dataset_stamp_ns: NO_DATASET_STAMP,
            width,
            height,
            stride: width,
            pixel_format: PixelFormat::Gray8.fourcc(),
            exposure_us: 0.0,
            gain_db: 0.0,
        }
    }

    /// Checks that the header describes pixels that fit in the frame.
    /// Returns the format and the number of pixel bytes in use.
    pub fn validate(&self) -> Result<(PixelFormat, usize), FrameError> {
        let sequence = self.sequence;
        if self.width == 0 || self.height == 0 {
            return Err(FrameError::ZeroSize {
                sequence,
                width: self.width,
                height: self.height,
            });
        }
        let format =
            PixelFormat::from_fourcc(self.pixel_format).ok_or(FrameError::UnknownFormat {
                sequence,
                fourcc: self.pixel_format,
            })?;
        let row_bytes = u64::from(self.width) * u64::from(format.bytes_per_pixel());
        if u64::from(self.stride) < row_bytes {
            return Err(FrameError::StrideTooSmall {
                sequence,
                stride: self.stride,
                row_bytes,
            });
        }
        let needed_bytes = u64::from(self.stride) * u64::from(self.height);
        let capacity_bytes = FRAME_CAPACITY_BYTES as u64;
        if needed_bytes > capacity_bytes
            || self.width > FRAME_MAX_WIDTH
            || self.height > FRAME_MAX_HEIGHT
        {
            return Err(FrameError::OverCapacity {
                sequence,
                width: self.width,
                height: self.height,
                stride: self.stride,
                needed_bytes,
                capacity_bytes,
            });
        }
        Ok((format, needed_bytes as usize))
    }
}

/// One camera frame in shared memory. About 3 MiB: never put one on the stack.
#[derive(ZeroCopySend)]
#[repr(C)]
#[type_name("star::Frame")]
pub struct Frame {
    /// Metadata; validate before trusting it.
    pub header: FrameHeader,
    /// Pixel storage; the first `stride * height` bytes are in use.
    pub pixels: [u8; FRAME_CAPACITY_BYTES],
}

impl std::fmt::Debug for Frame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Frame")
            .field("header", &self.header)
            .finish_non_exhaustive()
    }
}

impl Frame {
    /// A zeroed frame on the heap (tests, benchmarks, copies).
    pub fn boxed_zeroed() -> Box<Frame> {
        let layout = std::alloc::Layout::new::<Frame>();
        // SAFETY: `layout` has a non-zero size. Every field of `Frame` is an
        // integer, float or byte array, for which all-zero bytes are a valid
        // value, so the zeroed allocation is an initialized `Frame`, and it
        // was allocated by the global allocator with `Frame`'s layout as
        // `Box::from_raw` requires.
        unsafe {
            let ptr = std::alloc::alloc_zeroed(layout).cast::<Frame>();
            if ptr.is_null() {
                std::alloc::handle_alloc_error(layout);
            }
            Box::from_raw(ptr)
        }
    }

    /// Validates the header and borrows the frame as a view.
    pub fn view(&self) -> Result<FrameView<'_>, FrameError> {
        let (format, len) = self.header.validate()?;
        Ok(FrameView {
            header: &self.header,
            format,
            // validate() guarantees len <= FRAME_CAPACITY_BYTES.
            pixels: &self.pixels[..len],
        })
    }
}

/// A validated frame, borrowed in place (shared memory on the tracker side).
#[derive(Debug, Clone, Copy)]
pub struct FrameView<'a> {
    /// The header (already validated).
    pub header: &'a FrameHeader,
    /// The decoded pixel format.
    pub format: PixelFormat,
    /// `stride * height` bytes of pixels.
    pub pixels: &'a [u8],
}

impl<'a> FrameView<'a> {
    /// Width, pixels.
    pub fn width(&self) -> usize {
        self.header.width as usize
    }

    /// Height, pixels.
    pub fn height(&self) -> usize {
        self.header.height as usize
    }

    /// Row `y` (only the `width` pixels, without stride padding); `None` past the end.
    pub fn row(&self, y: usize) -> Option<&'a [u8]> {
        let stride = self.header.stride as usize;
        let row_bytes = self.width() * self.format.bytes_per_pixel() as usize;
        self.pixels.get(y * stride..y * stride + row_bytes)
    }

    /// Copies the pixels into `out` (resized in place), dropping stride padding.
    pub fn copy_to(&self, out: &mut crate::imgproc::ImageU8) {
        out.resize(self.width(), self.height(), 0);
        for y in 0..self.height() {
            if let Some(src) = self.row(y) {
                out.row_mut(y).copy_from_slice(src);
            }
        }
    }
}

/// Write access to a frame in a loaned, not yet published, shared-memory
/// sample: the header plus the whole pixel array.
pub struct FrameSlot<'a> {
    /// Header to fill in.
    pub header: &'a mut FrameHeader,
    /// The full pixel capacity; sources write rows at `stride` spacing.
    pub pixels: &'a mut [u8; FRAME_CAPACITY_BYTES],
}

impl<'a> FrameSlot<'a> {
    /// Borrows an initialized frame for writing (tests, heap frames).
    pub fn from_frame(frame: &'a mut Frame) -> Self {
        Self {
            header: &mut frame.header,
            pixels: &mut frame.pixels,
        }
    }

    /// Borrows a frame in a loaned shared-memory sample.
    ///
    /// # Safety
    /// The memory behind `frame` must be readable and writable bytes, which
    /// holds for iceoryx2 samples: the data segment is an mmap'd shared
    /// memory file that the kernel zero-fills at creation and that later
    /// frames only overwrite. Every bit pattern is a valid `Frame` (integers,
    /// floats and bytes only), so no byte is ever "uninitialized" in a way
    /// that could produce an invalid value.
    pub unsafe fn from_uninit(frame: &'a mut std::mem::MaybeUninit<Frame>) -> Self {
        // SAFETY: see the function contract above.
        let frame = unsafe { frame.assume_init_mut() };
        Self::from_frame(frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn consistent_header_is_accepted() {
        let h = FrameHeader::gray8(3, 640, 512);
        assert_eq!(h.validate(), Ok((PixelFormat::Gray8, 640 * 512)));
        let mut padded = h;
        padded.stride = 704;
        assert_eq!(padded.validate(), Ok((PixelFormat::Gray8, 704 * 512)));
        let max = FrameHeader::gray8(0, FRAME_MAX_WIDTH, FRAME_MAX_HEIGHT);
        assert!(max.validate().is_ok());
    }

    #[test]
    fn inconsistent_headers_are_rejected() {
        let ok = FrameHeader::gray8(7, 640, 512);
        let mut h = ok;
        h.width = 0;
        assert!(matches!(h.validate(), Err(FrameError::ZeroSize { .. })));
        let mut h = ok;
        h.height = 0;
        assert!(matches!(h.validate(), Err(FrameError::ZeroSize { .. })));
        let mut h = ok;
        h.pixel_format = u32::from_le_bytes(*b"YUYV");
        let err = h.validate().expect_err("unknown format");
        assert!(err.to_string().contains("unknown pixel format"), "{err}");
        let mut h = ok;
        h.stride = 639;
        assert!(matches!(
            h.validate(),
            Err(FrameError::StrideTooSmall { .. })
        ));
        let mut h = ok;
        h.width = FRAME_MAX_WIDTH + 1;
        h.stride = FRAME_MAX_WIDTH + 1;
        assert!(matches!(h.validate(), Err(FrameError::OverCapacity { .. })));
        let mut h = ok;
        h.stride = u32::MAX;
        h.height = u32::MAX;
        let err = h.validate().expect_err("over capacity, no overflow");
        assert!(err.to_string().contains("capacity"), "{err}");
    }

    #[test]
    fn view_exposes_rows_without_padding() {
        let mut frame = Frame::boxed_zeroed();
        frame.header = FrameHeader::gray8(1, 3, 2);
        frame.header.stride = 4;
        frame.pixels[..8].copy_from_slice(&[1, 2, 3, 99, 4, 5, 6, 99]);
        let view = frame.view().expect("valid");
        assert_eq!(view.row(0), Some(&[1u8, 2, 3][..]));
        assert_eq!(view.row(1), Some(&[4u8, 5, 6][..]));
        assert_eq!(view.row(2), None);
        let mut img = crate::imgproc::ImageU8::new(1, 1, 0);
        view.copy_to(&mut img);
        assert_eq!(img.data(), &[1, 2, 3, 4, 5, 6]);
    }

    #[test]
    fn header_layout_is_stable() {
        assert_eq!(std::mem::size_of::<FrameHeader>(), 48);
        assert_eq!(std::mem::offset_of!(Frame, pixels), 48);
        assert_eq!(
            PixelFormat::from_fourcc(PixelFormat::Gray8.fourcc()),
            Some(PixelFormat::Gray8)
        );
    }
}
