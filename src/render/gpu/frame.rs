//! Offscreen targets and readback for the wgpu renderer.
//!
//! Owns, for one image size: the gray and metric-depth color targets
//! (`R32Float`), the `Depth32Float` z-buffer, and two staging buffers. Each
//! staging buffer holds both planes with rows padded to 256 bytes
//! (`COPY_BYTES_PER_ROW_ALIGNMENT`), gray first. Two of them let the
//! readback of one keyframe overlap the render of the next. Takes a command
//! encoder to record the copies into; gives out the unpadded planes in a
//! [`RenderedView`].

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use crate::render::RenderedView;

/// Format of the gray and depth targets.
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// Format of the z-buffer.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Number of staging buffers.
pub const SLOTS: usize = 2;

/// Map state of a staging buffer, shared with the `map_async` callback.
const IDLE: u8 = 0;
const PENDING: u8 = 1;
const MAPPED: u8 = 2;
const FAILED: u8 = 3;

/// Where a staging buffer is in its cycle, as seen by [`FrameTargets`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapStatus {
    /// The map request has not completed yet.
    Pending,
    /// Mapped and readable.
    Mapped,
    /// The map request failed (device lost or buffer destroyed).
    Failed,
}

/// One staging buffer and its map state.
#[derive(Debug)]
struct Slot {
    buffer: wgpu::Buffer,
    state: Arc<AtomicU8>,
    busy: bool,
}

/// Targets and staging buffers for one image size.
#[derive(Debug)]
pub struct FrameTargets {
    width: u32,
    height: u32,
    padded_row_bytes: u32,
    gray: wgpu::Texture,
    depth_m: wgpu::Texture,
    /// View of the gray target.
    pub gray_view: wgpu::TextureView,
    /// View of the metric depth target.
    pub depth_view: wgpu::TextureView,
    /// View of the z-buffer.
    pub zbuffer_view: wgpu::TextureView,
    slots: [Slot; SLOTS],
    /// The metric depth plane, read back between the passes of the
    /// occlusion cull (`super::occlusion`).
    probe: Slot,
}

/// Bytes per row of a `width`-pixel, 4-byte-per-pixel image, padded for
/// texture-to-buffer copies.
pub fn padded_row_bytes(width: u32) -> u32 {
    let align = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    (width * 4).div_ceil(align) * align
}

fn target(
    device: &wgpu::Device,
    label: &str,
    w: u32,
    h: u32,
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    let mut usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
    if format == COLOR_FORMAT {
        usage |= wgpu::TextureUsages::COPY_SRC;
    }
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

impl FrameTargets {
    /// Allocates targets and staging for `width x height` (both non-zero and
    /// within the device's texture limit; the caller checks).
    pub fn new(device: &wgpu::Device, width: u32, height: u32) -> Self {
        let gray = target(device, "star gray target", width, height, COLOR_FORMAT);
        let depth_m = target(device, "star depth target", width, height, COLOR_FORMAT);
        let zbuffer = target(device, "star z-buffer", width, height, DEPTH_FORMAT);
        let padded = padded_row_bytes(width);
        let slot = || Slot {
            buffer: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("star readback staging"),
                size: 2 * u64::from(padded) * u64::from(height),
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            }),
            state: Arc::new(AtomicU8::new(IDLE)),
            busy: false,
        };
        Self {
            width,
            height,
            padded_row_bytes: padded,
            gray_view: gray.create_view(&wgpu::TextureViewDescriptor::default()),
            depth_view: depth_m.create_view(&wgpu::TextureViewDescriptor::default()),
            zbuffer_view: zbuffer.create_view(&wgpu::TextureViewDescriptor::default()),
            gray,
            depth_m,
            slots: [slot(), slot()],
            probe: Slot {
                buffer: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("star occlusion depth readback"),
                    size: u64::from(padded) * u64::from(height),
                    usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                    mapped_at_creation: false,
                }),
                state: Arc::new(AtomicU8::new(IDLE)),
                busy: false,
            },
        }
    }

    /// `(width, height)` of the targets.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Bytes allocated: the three 4-byte-per-pixel targets (gray, depth,
    /// z-buffer) and the staging buffers.
    pub fn bytes(&self) -> u64 {
        let targets = 3 * 4 * u64::from(self.width) * u64::from(self.height);
        targets + self.slots.iter().map(|s| s.buffer.size()).sum::<u64>() + self.probe.buffer.size()
    }

    /// A staging slot with no readback in flight, if any.
    pub fn free_slot(&self) -> Option<usize> {
        self.slots.iter().position(|s| !s.busy)
    }

    /// True when some readback is in flight.
    pub fn any_busy(&self) -> bool {
        self.slots.iter().any(|s| s.busy)
    }

    fn plane_bytes(&self) -> u64 {
        u64::from(self.padded_row_bytes) * u64::from(self.height)
    }

    /// Records the copies of both targets into staging slot `slot`.
    pub fn record_copies(&self, encoder: &mut wgpu::CommandEncoder, slot: usize) {
        let Some(s) = self.slots.get(slot) else {
            return;
        };
        let extent = wgpu::Extent3d {
            width: self.width,
            height: self.height,
            depth_or_array_layers: 1,
        };
        for (texture, offset) in [(&self.gray, 0), (&self.depth_m, self.plane_bytes())] {
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &s.buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset,
                        bytes_per_row: Some(self.padded_row_bytes),
                        rows_per_image: Some(self.height),
                    },
                },
                extent,
            );
        }
    }

    /// Records the copy of the metric depth target into the probe buffer
    /// and (once submitted, with [`FrameTargets::request_probe_map`]) reads
    /// it back between two passes.
    pub fn record_probe_copy(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.depth_m,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.probe.buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_row_bytes),
                    rows_per_image: Some(self.height),
                },
            },
            wgpu::Extent3d {
                width: self.width,
                height: self.height,
                depth_or_array_layers: 1,
            },
        );
    }

    /// Requests the mapping of the probe buffer (after its copy was
    /// submitted).
    pub fn request_probe_map(&mut self) {
        let s = &mut self.probe;
        s.busy = true;
        s.state.store(PENDING, Ordering::Release);
        let state = Arc::clone(&s.state);
        s.buffer.map_async(wgpu::MapMode::Read, .., move |result| {
            let value = if result.is_ok() { MAPPED } else { FAILED };
            state.store(value, Ordering::Release);
        });
    }

    /// Gives the mapped probe's rows (`width` pixels of `f32` bytes each,
    /// top first) to `read`, then unmaps it; or, when it is not mapped,
    /// only releases it. Returns whether `read` ran.
    pub fn read_probe(&mut self, read: impl FnOnce(&mut dyn Iterator<Item = &[f32]>)) -> bool {
        let padded = self.padded_row_bytes as usize;
        let row_bytes = self.width as usize * 4;
        let s = &mut self.probe;
        let ok = s.state.load(Ordering::Acquire) == MAPPED
            && match s.buffer.get_mapped_range(..) {
                Ok(view) => {
                    let bytes: &[u8] = &view;
                    // Mapped ranges are aligned far beyond 4 bytes, and
                    // rows are padded to 256.
                    match bytemuck::try_cast_slice::<u8, f32>(bytes) {
                        Ok(pixels) => {
                            let mut rows = pixels
                                .chunks(padded / 4)
                                .map(|r| r.get(..row_bytes / 4).unwrap_or(r));
                            read(&mut rows);
                            true
                        }
                        Err(_) => false,
                    }
                }
                Err(_) => false,
            };
        if matches!(s.state.load(Ordering::Acquire), PENDING | MAPPED) {
            s.buffer.unmap();
        }
        s.state.store(IDLE, Ordering::Release);
        s.busy = false;
        ok
    }

    /// Requests the mapping of slot `slot` (after its copies were submitted).
    pub fn request_map(&mut self, slot: usize) {
        let Some(s) = self.slots.get_mut(slot) else {
            return;
        };
        s.busy = true;
        s.state.store(PENDING, Ordering::Release);
        let state = Arc::clone(&s.state);
        s.buffer.map_async(wgpu::MapMode::Read, .., move |result| {
            let value = if result.is_ok() { MAPPED } else { FAILED };
            state.store(value, Ordering::Release);
        });
    }

    /// The map state of slot `slot`.
    pub fn status(&self, slot: usize) -> MapStatus {
        match self
            .slots
            .get(slot)
            .map(|s| s.state.load(Ordering::Acquire))
        {
            Some(MAPPED) => MapStatus::Mapped,
            Some(PENDING) => MapStatus::Pending,
            _ => MapStatus::Failed,
        }
    }

    /// Copies the mapped planes of `slot` into `out` (sized `width x
    /// height`, checked by the caller), then unmaps and frees the slot.
    /// Returns false if the mapped range could not be read.
    pub fn unpack(&mut self, slot: usize, out: &mut RenderedView) -> bool {
        let plane = self.plane_bytes() as usize;
        let padded = self.padded_row_bytes as usize;
        let row_bytes = self.width as usize * 4;
        let Some(s) = self.slots.get_mut(slot) else {
            return false;
        };
        let ok = match s.buffer.get_mapped_range(..) {
            Ok(view) => {
                let bytes: &[u8] = &view;
                for (plane_offset, image) in [(0, &mut out.gray), (plane, &mut out.depth_m)] {
                    for (y, dst) in image.data_mut().chunks_exact_mut(row_bytes / 4).enumerate() {
                        let start = plane_offset + y * padded;
                        let Some(src) = bytes.get(start..start + row_bytes) else {
                            break;
                        };
                        for (d, s) in dst.iter_mut().zip(src.chunks_exact(4)) {
                            *d = f32::from_ne_bytes([s[0], s[1], s[2], s[3]]);
                        }
                    }
                }
                true
            }
            Err(_) => false,
        };
        s.buffer.unmap();
        s.state.store(IDLE, Ordering::Release);
        s.busy = false;
        ok
    }

    /// Abandons the readback in `slot` (after a failure), unmapping if needed.
    pub fn release(&mut self, slot: usize) {
        if let Some(s) = self.slots.get_mut(slot) {
            if matches!(s.state.load(Ordering::Acquire), PENDING | MAPPED) {
                // Unmapping also aborts a pending map request.
                s.buffer.unmap();
            }
            s.state.store(IDLE, Ordering::Release);
            s.busy = false;
        }
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_padded_to_256_bytes() {
        assert_eq!(padded_row_bytes(640), 2560);
        assert_eq!(padded_row_bytes(1), 256);
        assert_eq!(padded_row_bytes(65), 512);
        assert_eq!(
            padded_row_bytes(100) % wgpu::COPY_BYTES_PER_ROW_ALIGNMENT,
            0
        );
    }
}
