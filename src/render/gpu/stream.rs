//! Chunk streaming for the wgpu renderer under a device-memory budget
//! (`[render] gpu_budget_mb`).
//!
//! Owns, when the mesh's vertex and index data exceed the budget, a fixed
//! pool of chunk slots: one vertex and one index buffer, allocated once at
//! start and cut into equal slots that each hold the largest chunk; the
//! host copy of the chunked vertices and of the indices rebased to each
//! chunk's first vertex (what uploads read); and the slot tables
//! ([`SlotTable`]: the chunk in each slot, the slot of each chunk, a use
//! stamp per slot). Takes, per render pass, the visible chunks to draw (at
//! most one per slot, in index-buffer order); uploads those not resident
//! with `queue.write_buffer` into a free slot, else the least recently used
//! one that this pass does not need; gives out the pass's draw calls (the
//! slot's index range, and the slot's first vertex as `base_vertex`).
//! Nothing allocates after construction. Counts uploads and evictions
//! ([`StreamStats`]).
//!
//! `write_buffer` takes effect before the next `queue.submit`, so a render
//! that needs more chunks than the pool holds submits each pass before
//! uploading the next pass's chunks (see `super::renderer`).

use super::draws::Draw;
use super::upload::GpuVertex;
use super::GpuError;
use crate::render::chunks::{ChunkedMesh, MeshChunk};

/// Bytes of one vertex on the device.
const VERTEX_BYTES: u64 = std::mem::size_of::<GpuVertex>() as u64;
/// Bytes of one index on the device (`u32`).
const INDEX_BYTES: u64 = 4;
/// Bytes in the MB of `gpu_budget_mb`.
const BYTES_PER_MB: f64 = crate::render::select::BYTES_PER_MB;
/// `SlotTable::chunk_slot` of a chunk that is not resident.
const NO_SLOT: u32 = u32::MAX;
/// `SlotTable::slot_chunk` of a slot that holds nothing.
const NO_CHUNK: u32 = u32::MAX;

/// Counts of the wgpu renderer's mesh streaming since it started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Chunk slots in the pool; 0 when the whole mesh is resident (no
    /// budget, or the mesh within it).
    pub slots: usize,
    /// Bytes of one slot (vertices and indices of the largest chunk); 0
    /// when the whole mesh is resident.
    pub slot_bytes: u64,
    /// Renders submitted.
    pub renders: u64,
    /// Render passes recorded: one per render, more for a view that needed
    /// more chunks than the pool holds.
    pub passes: u64,
    /// Chunks written into a slot.
    pub uploads: u64,
    /// Uploads that replaced a resident chunk.
    pub evictions: u64,
}

/// The pool's shape: how many slots, and what one slot holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamPlan {
    /// Slots in the pool.
    pub slots: usize,
    /// Vertices one slot holds (the largest chunk's).
    pub slot_vertices: u32,
    /// Indices one slot holds (the largest chunk's).
    pub slot_indices: u32,
}

impl StreamPlan {
    /// Bytes of one slot's vertices.
    fn slot_vertex_bytes(&self) -> u64 {
        u64::from(self.slot_vertices) * VERTEX_BYTES
    }

    /// Bytes of one slot's indices.
    fn slot_index_bytes(&self) -> u64 {
        u64::from(self.slot_indices) * INDEX_BYTES
    }

    /// Bytes of one slot, vertices and indices.
    pub fn slot_bytes(&self) -> u64 {
        self.slot_vertex_bytes() + self.slot_index_bytes()
    }
}

/// `bytes` in MB, rounded up to the kB (a minimum that is enough).
fn mb_rounded_up(bytes: u64) -> f64 {
    bytes.div_ceil(1000) as f64 * 1000.0 / BYTES_PER_MB
}

/// Decides how the mesh lives on the device: `None` for wholly resident
/// (`budget_bytes` 0, or `resident_bytes`, its vertex and index buffers,
/// within the budget), else the pool that fits the budget and the
/// adapter's `max_buffer_bytes`. Fails when the budget cannot hold one
/// slot of the largest chunk.
pub fn plan(
    chunks: &[MeshChunk],
    resident_bytes: u64,
    budget_bytes: u64,
    max_buffer_bytes: u64,
) -> Result<Option<StreamPlan>, GpuError> {
    if budget_bytes == 0 || resident_bytes <= budget_bytes {
        return Ok(None);
    }
    let largest = |count: fn(&MeshChunk) -> usize| {
        chunks
            .iter()
            .map(count)
            .max()
            .and_then(|n| u32::try_from(n).ok())
            .unwrap_or(0)
    };
    let one = StreamPlan {
        slots: 1,
        slot_vertices: largest(|c| c.vertices.len()),
        slot_indices: largest(|c| 3 * c.triangle_count()),
    };
    if one.slot_vertices == 0 || one.slot_indices == 0 {
        // Nothing to draw: the (padded) resident buffers are as small as it gets.
        return Ok(None);
    }
    if budget_bytes < one.slot_bytes() {
        return Err(GpuError::BudgetTooSmall {
            budget_mb: budget_bytes as f64 / BYTES_PER_MB,
            min_mb: mb_rounded_up(one.slot_bytes()),
            mesh_mb: mb_rounded_up(resident_bytes),
            chunks: chunks.len(),
            triangles: chunks.iter().map(MeshChunk::triangle_count).sum(),
        });
    }
    let slots = (budget_bytes / one.slot_bytes())
        .min(max_buffer_bytes / one.slot_vertex_bytes())
        .min(max_buffer_bytes / one.slot_index_bytes())
        // `base_vertex` is an `i32`, index ranges are `u32`.
        .min(i32::MAX as u64 / u64::from(one.slot_vertices))
        .min(u64::from(u32::MAX) / u64::from(one.slot_indices))
        .min(chunks.len() as u64);
    if slots == 0 {
        return Err(GpuError::MeshTooLarge {
            bytes: one.slot_vertex_bytes().max(one.slot_index_bytes()),
            max_bytes: max_buffer_bytes,
        });
    }
    Ok(Some(StreamPlan {
        slots: slots as usize,
        ..one
    }))
}

/// Which chunk each slot holds, and the least-recently-used choice of the
/// slot a chunk goes into. No device; see the [module docs](self).
#[derive(Debug)]
pub struct SlotTable {
    /// Per chunk, its slot, or [`NO_SLOT`].
    chunk_slot: Vec<u32>,
    /// Per slot, its chunk, or [`NO_CHUNK`].
    slot_chunk: Vec<u32>,
    /// Per slot, the last pass that drew it (0: never; free slots go first).
    slot_used: Vec<u64>,
    /// The current pass, counted from 1.
    pass: u64,
    uploads: u64,
    evictions: u64,
}

/// Where [`SlotTable::place`] put a chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Placement {
    /// The slot.
    pub slot: u32,
    /// True when the chunk was not resident: its data must be written.
    pub upload: bool,
}

impl SlotTable {
    /// `slots` empty slots for a mesh of `chunks` chunks.
    pub fn new(chunks: usize, slots: usize) -> Self {
        Self {
            chunk_slot: vec![NO_SLOT; chunks],
            slot_chunk: vec![NO_CHUNK; slots],
            slot_used: vec![0; slots],
            pass: 0,
            uploads: 0,
            evictions: 0,
        }
    }

    /// Starts a pass that draws `batch` (at most one chunk per slot): its
    /// resident chunks are marked used first, so that no upload of this
    /// pass evicts them.
    pub fn begin_pass(&mut self, batch: &[u32]) {
        self.pass += 1;
        for &chunk in batch {
            let slot = self.chunk_slot.get(chunk as usize).copied();
            if let Some(used) = slot.and_then(|s| self.slot_used.get_mut(s as usize)) {
                *used = self.pass;
            }
        }
    }

    /// The slot of `chunk` in this pass: where it is, or a free slot, or
    /// the least recently used one not used by this pass (its chunk
    /// evicted). `None` when every slot is used by this pass or `chunk` is
    /// out of range.
    pub fn place(&mut self, chunk: u32) -> Option<Placement> {
        let resident = *self.chunk_slot.get(chunk as usize)?;
        if resident != NO_SLOT {
            return Some(Placement {
                slot: resident,
                upload: false,
            });
        }
        // The first of the least recently used (free slots have stamp 0).
        let (slot, _) = self
            .slot_used
            .iter()
            .enumerate()
            .filter(|&(_, &used)| used < self.pass)
            .min_by_key(|&(_, &used)| used)?;
        let old = self.slot_chunk.get(slot).copied().unwrap_or(NO_CHUNK);
        if let Some(old_slot) = self.chunk_slot.get_mut(old as usize) {
            *old_slot = NO_SLOT;
            self.evictions += 1;
        }
        if let (Some(c), Some(used)) = (self.slot_chunk.get_mut(slot), self.slot_used.get_mut(slot))
        {
            *c = chunk;
            *used = self.pass;
        }
        if let Some(s) = self.chunk_slot.get_mut(chunk as usize) {
            *s = slot as u32;
        }
        self.uploads += 1;
        Some(Placement {
            slot: slot as u32,
            upload: true,
        })
    }

    /// Chunks written into slots so far.
    pub fn uploads(&self) -> u64 {
        self.uploads
    }

    /// Uploads that replaced a resident chunk so far.
    pub fn evictions(&self) -> u64 {
        self.evictions
    }
}

/// The slot pool on the device and the host data it is filled from.
#[derive(Debug)]
pub struct StreamPool {
    plan: StreamPlan,
    /// `plan.slots` slots of `plan.slot_vertices` [`GpuVertex`]es.
    pub vertices: wgpu::Buffer,
    /// `plan.slots` slots of `plan.slot_indices` `u32` indices, each
    /// relative to its slot's first vertex.
    pub indices: wgpu::Buffer,
    /// The chunked vertices, chunk by chunk.
    host_vertices: Vec<GpuVertex>,
    /// The chunked indices, each minus its chunk's first vertex.
    host_indices: Vec<u32>,
    table: SlotTable,
}

impl StreamPool {
    /// Allocates the pool of `plan` (empty) and keeps `host_vertices` (the
    /// chunked vertices) and the indices of `chunked`, rebased per chunk.
    pub fn new(
        device: &wgpu::Device,
        plan: StreamPlan,
        host_vertices: Vec<GpuVertex>,
        chunked: &ChunkedMesh,
    ) -> Self {
        let mut host_indices = chunked.indices.clone();
        for chunk in &chunked.chunks {
            let range = chunk.index_range();
            if let Some(indices) = host_indices.get_mut(range.start as usize..range.end as usize) {
                // A chunk's triangles use its own vertices only.
                for i in indices {
                    *i = i.saturating_sub(chunk.vertices.start);
                }
            }
        }
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let slots = plan.slots as u64;
        Self {
            vertices: buffer(
                "star mesh vertex slots",
                slots * plan.slot_vertex_bytes(),
                wgpu::BufferUsages::VERTEX,
            ),
            indices: buffer(
                "star mesh index slots",
                slots * plan.slot_index_bytes(),
                wgpu::BufferUsages::INDEX,
            ),
            host_vertices,
            host_indices,
            table: SlotTable::new(chunked.chunks.len(), plan.slots),
            plan,
        }
    }

    /// The pool's shape.
    pub fn plan(&self) -> StreamPlan {
        self.plan
    }

    /// Bytes of the slot buffers on the device.
    pub fn bytes(&self) -> u64 {
        self.vertices.size() + self.indices.size()
    }

    /// Chunk uploads and evictions so far.
    pub fn counts(&self) -> (u64, u64) {
        (self.table.uploads(), self.table.evictions())
    }

    /// Makes the chunks of `batch` (at most [`StreamPlan::slots`], each
    /// with a bind group in `chunk_texture`) resident, writing those that
    /// are not with `queue`, and fills `draws` (cleared first) with one
    /// draw per chunk, in `batch` order.
    pub fn load(
        &mut self,
        queue: &wgpu::Queue,
        chunks: &[MeshChunk],
        chunk_texture: &[Option<usize>],
        batch: &[u32],
        draws: &mut Vec<Draw>,
    ) {
        self.table.begin_pass(batch);
        draws.clear();
        for &c in batch {
            let (Some(chunk), Some(&Some(texture))) =
                (chunks.get(c as usize), chunk_texture.get(c as usize))
            else {
                continue;
            };
            let Some(placement) = self.table.place(c) else {
                continue;
            };
            if placement.upload {
                self.write(queue, chunk, placement.slot);
            }
            let first_index = placement.slot * self.plan.slot_indices;
            let index_count = 3 * chunk.triangle_count() as u32;
            draws.push(Draw {
                indices: first_index..first_index + index_count,
                // Below i32::MAX: see `plan`.
                base_vertex: (placement.slot * self.plan.slot_vertices) as i32,
                texture,
            });
        }
    }

    /// Writes `chunk`'s vertices and indices into `slot`.
    fn write(&self, queue: &wgpu::Queue, chunk: &MeshChunk, slot: u32) {
        let vertices = chunk.vertices.start as usize..chunk.vertices.end as usize;
        let indices = chunk.index_range();
        let (Some(vertices), Some(indices)) = (
            self.host_vertices.get(vertices),
            self.host_indices
                .get(indices.start as usize..indices.end as usize),
        ) else {
            return;
        };
        let slot = u64::from(slot);
        queue.write_buffer(
            &self.vertices,
            slot * self.plan.slot_vertex_bytes(),
            bytemuck::cast_slice(vertices),
        );
        queue.write_buffer(
            &self.indices,
            slot * self.plan.slot_index_bytes(),
            bytemuck::cast_slice(indices),
        );
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::render::chunks::Aabb;

    fn chunk(triangles: u32, vertices: u32) -> MeshChunk {
        MeshChunk {
            triangles: 0..triangles,
            vertices: 0..vertices,
            group: 0,
            bounds: Aabb {
                min_m: [0.0; 3],
                max_m: [1.0; 3],
            },
        }
    }

    #[test]
    fn plan_fits_the_budget_and_rejects_one_below_a_chunk() {
        // Largest chunk: 100 triangles (1200 index bytes), 80 vertices
        // (1920 vertex bytes): 3120 bytes a slot.
        let chunks = [chunk(100, 60), chunk(50, 80), chunk(10, 10)];
        let resident = 10_000;
        let max = u64::MAX;
        assert_eq!(plan(&chunks, resident, 0, max).unwrap(), None, "no budget");
        assert_eq!(plan(&chunks, resident, resident, max).unwrap(), None);
        let p = plan(&chunks, resident, 7000, max).unwrap().unwrap();
        assert_eq!((p.slots, p.slot_vertices, p.slot_indices), (2, 80, 300));
        assert_eq!(p.slot_bytes(), 3120);
        assert!(p.slots as u64 * p.slot_bytes() <= 7000);
        // The adapter's buffer limit caps the slots.
        let capped = plan(&chunks, resident, 7000, 2000).unwrap().unwrap();
        assert_eq!(capped.slots, 1);
        let err = plan(&chunks, resident, 3119, max).expect_err("below one slot");
        let text = err.to_string();
        assert!(
            text.contains("render.gpu_budget_mb") && text.contains("minimum is 0.004 MB"),
            "{text}"
        );
        // An empty mesh is never streamed.
        assert_eq!(plan(&[], 36, 1, max).unwrap(), None);
    }

    #[test]
    fn slots_go_free_first_then_least_recently_used_never_within_a_pass() {
        let mut t = SlotTable::new(6, 3);
        t.begin_pass(&[0, 1]);
        let p = |slot, upload| Some(Placement { slot, upload });
        assert_eq!(t.place(0), p(0, true));
        assert_eq!(t.place(1), p(1, true));
        // Chunk 1 again and chunk 2: 1 stays, 2 takes the free slot, then
        // 3 evicts 0 (least recently used), not 1 or 2.
        t.begin_pass(&[1, 2, 3]);
        assert_eq!(t.place(1), p(1, false));
        assert_eq!(t.place(2), p(2, true));
        assert_eq!(t.place(3), p(0, true));
        assert_eq!((t.uploads(), t.evictions()), (4, 1));
        // A chunk resident at the start of a pass is kept even when it
        // comes last in the batch.
        t.begin_pass(&[4, 5, 1]);
        assert_eq!(t.place(4), p(0, true), "oldest, first");
        assert_eq!(t.place(5), p(2, true));
        assert_eq!(t.place(1), p(1, false));
        // Every slot is used by this pass: no room for a fourth chunk.
        assert_eq!(t.place(0), None);
        assert_eq!(t.place(99), None, "out of range");
        assert_eq!((t.uploads(), t.evictions()), (6, 3));
    }
}
