//! The batches of one CPU render: which chunks and clusters each sets up,
//! and the two stages run on them.
//!
//! Takes the chunks that passed the frustum test, the renderer's scratch
//! and, with the occlusion cull, its [`Occlusion`] state; runs [`setup`]
//! and [`raster`] once (no occlusion cull) or once per batch: first the
//! clusters the previous render saw (when its camera was near), else the
//! nearest chunks, then the rest nearest first in growing batches, each
//! later batch without what the tiles of the earlier ones hide. Gives out
//! the finished image and the counts of what was skipped and binned.
//!
//! [`setup`]: super::setup
//! [`raster`]: super::raster

use rayon::iter::Either;
use rayon::prelude::*;

use super::occlusion::{self, Occlusion};
use super::raster;
use super::setup::{ChunkSetup, Clusters, SetupSlot, BAND_ROWS};
use super::view::View;
use crate::map::GrayTexture;
use crate::render::chunks::{ChunkedMesh, MeshChunk};
use crate::render::frustum::Frustum;
use crate::render::RenderedView;

/// Runs the two stages on the chunks marked in `visible`: all at once, or,
/// with `occlusion`, in batches (see the module docs), each later batch without the
/// chunks and triangles hidden behind what the earlier ones drew
/// ([`occlusion`]). `setups` has one element per chunk; each chunk of a
/// batch is set up in a slot of `pool`, which grows to the largest batch
/// (slot `k` holds the batch's `k`-th chunk). `out` has been checked
/// against `view`; `tri_order` has one element per pixel; `batch` has room
/// for every chunk. Returns the chunks and triangles (in those chunks) the
/// occlusion cull skipped, and the screen triangles binned.
#[allow(clippy::too_many_arguments)]
pub(super) fn draw(
    mesh: &ChunkedMesh,
    textures: &[GrayTexture],
    visible: &[bool],
    (setups, pool): (&[ChunkSetup], &mut Vec<SetupSlot>),
    (view, frustum): (&View, Option<&Frustum>),
    tri_order: &mut [u32],
    out: &mut RenderedView,
    occlusion: Option<(&mut Occlusion, [f64; 3])>,
    batch: &mut Vec<u32>,
) -> (usize, usize, usize) {
    let bands = view.height.div_ceil(BAND_ROWS);
    let mut occlusion = occlusion.map(|(occ, position_m)| {
        occ.prepare(&mesh.chunks, visible, view, position_m);
        occ
    });
    let first_batch = occlusion
        .as_deref()
        .map_or(0, |occ| occlusion::first_batch(occ.order.len()));
    // Next chunk of the nearest-first order to consider.
    let mut cursor = 0;
    let mut skipped = (0, 0);
    let mut binned = 0;
    for pass in 0.. {
        batch.clear();
        let last = match occlusion.as_deref() {
            None => {
                batch.extend((0..visible.len() as u32).filter(|&i| visible[i as usize]));
                true
            }
            Some(occ) if pass == 0 && occ.coherent => {
                // What the previous render saw, untested.
                batch.extend(
                    occ.order
                        .iter()
                        .copied()
                        .filter(|&i| occ.chunk_seen_before.get(i as usize) == Some(&true)),
                );
                false
            }
            Some(occ) => {
                let order = &occ.order;
                // The first batch untested; then twice as many drawn chunks
                // each batch, the last batch taking the rest.
                let quota = if pass + 1 >= occlusion::MAX_BATCHES {
                    usize::MAX
                } else {
                    first_batch << pass
                };
                while cursor < order.len() && batch.len() < quota {
                    let i = order[cursor];
                    cursor += 1;
                    let drawn_before = occ.chunk_seen_before.get(i as usize) == Some(&true);
                    if pass > 0 && occ.hidden(i as usize) {
                        if drawn_before {
                            // Its other clusters are hidden.
                            continue;
                        }
                        skipped.0 += 1;
                        skipped.1 += mesh
                            .chunks
                            .get(i as usize)
                            .map_or(0, MeshChunk::triangle_count);
                    } else {
                        batch.push(i);
                    }
                }
                cursor >= order.len()
            }
        };
        if pool.len() < batch.len() {
            // The largest batch so far: the pool grows once to it.
            pool.resize_with(batch.len(), SetupSlot::default);
        }
        let slots = &mut pool[..batch.len()];
        let occluders = occlusion
            .as_deref()
            .filter(|_| pass > 0)
            .map(Occlusion::tiles);
        let occ = occlusion.as_deref();
        slots
            .par_iter_mut()
            .zip(batch.par_iter())
            .for_each(|(scratch, &i)| {
                let i = i as usize;
                let (Some(chunk), Some(setup)) = (mesh.chunks.get(i), setups.get(i)) else {
                    // Not a chunk of this mesh: nothing to draw in its slot.
                    scratch.clear();
                    return;
                };
                // With a coherent first batch, each chunk's clusters the
                // previous render saw are drawn in it, the rest later.
                let clusters = match occ {
                    Some(occ) if occ.coherent && occ.chunk_seen_before.get(i) == Some(&true) => {
                        let before = occ.clusters_seen_before(i);
                        if pass == 0 {
                            Clusters::Only(before)
                        } else {
                            Clusters::Except(before)
                        }
                    }
                    _ => Clusters::All,
                };
                let first_cluster = occ.map_or(0, |o| o.first_cluster(i));
                scratch.build(
                    (chunk, setup),
                    mesh,
                    (view, bands),
                    (frustum, occluders),
                    (clusters, first_cluster),
                );
            });
        binned += slots.iter().map(|c| c.tris.len()).sum::<usize>();
        let stage = (pass == 0, last);
        let band_len = view.width * BAND_ROWS;
        // The bands mark the chunks seen, and fill the occlusion tiles (the
        // rows under each) between batches.
        let (tile_rows, seen) = match occlusion.as_deref_mut() {
            Some(occ) => {
                let (tiles, per_band, seen) = occ.raster_targets();
                let rows = if last {
                    Either::Right((0..bands).into_par_iter().map(no_tiles))
                } else {
                    Either::Left(tiles.par_chunks_mut(per_band).map(Some))
                };
                (rows, Some(seen))
            }
            None => (
                Either::Right((0..bands).into_par_iter().map(no_tiles)),
                None,
            ),
        };
        let drawn = (&pool[..batch.len()], seen);
        out.gray
            .data_mut()
            .par_chunks_mut(band_len)
            .zip(out.depth_m.data_mut().par_chunks_mut(band_len))
            .zip(tri_order.par_chunks_mut(band_len))
            .zip(tile_rows)
            .enumerate()
            .for_each(|(band, (((gray, depth_m), order), tiles))| {
                raster::draw_band(
                    band,
                    view.width,
                    view.min_inv_z,
                    stage,
                    drawn,
                    textures,
                    gray,
                    depth_m,
                    order,
                    tiles,
                );
            });
        if last {
            break;
        }
    }
    (skipped.0, skipped.1, binned)
}

/// No occlusion tiles for a band to fill.
fn no_tiles<'a>(_band: usize) -> Option<&'a mut [f32]> {
    None
}
