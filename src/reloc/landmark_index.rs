//! Which landmarks a frame's corners are compared with: sub-linear in the
//! map instead of every landmark.
//!
//! Takes the database's landmarks (stored leaf after leaf of its
//! [`Vocabulary`]) at construction; gives, per query descriptor, the best
//! and second-best landmark by Hamming distance among those searched, as
//! [`super::features::best_two`] does over all of them, and counts the
//! comparisons.
//! - Near a known position ([`LandmarkIndex::best_two_near`]): the
//!   landmarks lie in square cells of the floor plan; the cells within the
//!   reach of the position are gathered ring by ring outward from it. Up to
//!   [`NEAR_EXACT_MAX`] landmarks, each corner is compared with every one
//!   gathered (exact within reach); beyond, through the vocabulary as over
//!   the whole map (with more probes), the landmarks out of reach skipped.
//!   Within each leaf the landmarks are ordered by a coarser floor-plan
//!   block, so that a probed leaf is read only over the blocks that meet
//!   the reach (one run of blocks per block row), not whole.
//! - Over the whole map ([`LandmarkIndex::best_two_everywhere`]): each
//!   corner descends the vocabulary to its [`Probes::words`] nearest words
//!   and, under them, its [`Probes::leaves`] nearest leaves, and is
//!   compared with the landmarks of those leaves only (an inverted index:
//!   approximate, the nearest landmark can lie in a leaf not probed).
//! - Both vocabulary searches read the probed leaves leaf-major: all the
//!   corners' probes first, then each probed leaf once, in memory order,
//!   for every corner that probes it. Corner after corner, the leaves
//!   were scattered reads, each a cache miss; in order they stream. Of
//!   equal distances found in different leaves the lower landmark index
//!   wins, so the order in which the leaves are read does not change the
//!   result.
//!
//! All scratch is sized at construction: nothing allocates per query.

use super::descriptor::Descriptor;
use super::features::{best_two, best_two_batch};
use super::landmarks::Landmark;
use super::vocabulary::{Vocabulary, MAX_WORDS};

/// Edge of the floor-plan cells, meters (larger on a map so wide that the
/// grid would pass [`MAX_CELLS`]).
const CELL_M: f32 = 1.0;
/// Most cells of the floor-plan grid.
const MAX_CELLS: usize = 1 << 22;
/// Edge of the blocks that order the landmarks within a leaf, meters
/// (larger where leaves x blocks would pass [`MAX_LEAF_BLOCKS`]).
const BLOCK_M: f32 = 2.0;
/// Most entries of the leaf-by-block table (4 bytes each).
const MAX_LEAF_BLOCKS: usize = 1 << 22;
/// Near a known position, up to this many landmarks within reach are each
/// compared with every corner (exact); beyond, the vocabulary is searched
/// with [`NEAR_PROBES`], skipping the landmarks out of reach.
pub const NEAR_EXACT_MAX: usize = 16_384;
/// The probes of the near search beyond [`NEAR_EXACT_MAX`]: more than over
/// the whole map, since most landmarks of a probed leaf are out of reach.
const NEAR_PROBES: Probes = Probes {
    words: 8,
    leaves: 32,
};

/// How many vocabulary nodes a corner descends into over the whole map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Probes {
    /// Nearest top-level words followed (at most [`MAX_WORDS`]).
    pub words: usize,
    /// Nearest leaves under those words whose landmarks are compared
    /// (at most [`MAX_PROBED_LEAVES`]).
    pub leaves: usize,
}

/// Most leaves probed per corner.
pub const MAX_PROBED_LEAVES: usize = 64;
/// Queries per search the scratch is sized for at construction (a frame's
/// corners; more grow it once).
const PREALLOCATED_QUERIES: usize = 1024;

impl Default for Probes {
    fn default() -> Self {
        Self {
            words: 4,
            leaves: 12,
        }
    }
}

/// Best two matches of one query: (best distance, best index, second
/// distance, second index), `u32::MAX` where missing.
pub type BestTwo = (u32, u32, u32, u32);

/// The landmarks laid out for matching. See the module docs.
#[derive(Debug, Clone)]
pub struct LandmarkIndex {
    /// Descriptors leaf after leaf as the database stores them, within a
    /// leaf ordered by block: position `p` holds landmark `original[p]`.
    descriptors: Vec<Descriptor>,
    original: Vec<u32>,
    vocabulary: Vocabulary,
    /// First leaf of each word; first landmark of each leaf (and the end).
    word_first_leaf: Vec<u32>,
    leaf_start: Vec<u32>,
    /// Floor-plan grid: origin (x, y), cell edge, size; landmarks per cell
    /// (indices, cell after cell) and where each cell's start.
    origin_m: [f32; 2],
    cell_m: f32,
    nx: usize,
    ny: usize,
    cell_start: Vec<u32>,
    /// Positions (in `descriptors`) of each cell's landmarks.
    cell_landmarks: Vec<u32>,
    /// Block grid over the same origin: edge, size; per leaf, the
    /// position where each of its blocks starts (`n_blocks + 1` each).
    block_m: f32,
    block_nx: usize,
    block_ny: usize,
    leaf_block_start: Vec<u32>,
    /// Scratch of the near search: the runs of blocks within reach
    /// (first block, end block), one per block row.
    near_runs: Vec<(u32, u32)>,
    /// Scratch of the vocabulary search: (probed leaf, query) pairs.
    probe_pairs: Vec<(u32, u32)>,
    /// Scratch of the near search: the gathered descriptors and indices.
    near_descriptors: Vec<Descriptor>,
    near_indices: Vec<u32>,
    /// Per landmark, the epoch of the last near search that gathered it.
    near_mark: Vec<u32>,
    epoch: u32,
    probes: Probes,
    near_probes: Probes,
    comparisons: u64,
}

impl LandmarkIndex {
    /// Lays out `landmarks` (stored leaf after leaf of `vocabulary`; an
    /// inconsistent vocabulary is replaced by one leaf holding them all,
    /// which makes the whole-map search brute force).
    pub fn new(landmarks: &[Landmark], vocabulary: &Vocabulary) -> Self {
        Self::with_block(landmarks, vocabulary, BLOCK_M)
    }

    /// [`Self::new`] with the blocks' edge given (`f32::INFINITY`: one
    /// block, a probed leaf read whole).
    fn with_block(landmarks: &[Landmark], vocabulary: &Vocabulary, block_m: f32) -> Self {
        let n = landmarks.len();
        let vocabulary = if vocabulary.check(n as u64).is_ok() && !vocabulary.is_empty() {
            vocabulary.clone()
        } else {
            Vocabulary {
                words: vec![Descriptor::default()],
                word_leaves: vec![1],
                leaves: vec![Descriptor::default()],
                leaf_sizes: vec![n as u32],
            }
        };
        let mut word_first_leaf = Vec::with_capacity(vocabulary.words.len() + 1);
        let mut first = 0u32;
        for &k in &vocabulary.word_leaves {
            word_first_leaf.push(first);
            first += k;
        }
        word_first_leaf.push(first);
        let mut leaf_start = Vec::with_capacity(vocabulary.leaves.len() + 1);
        let mut start = 0u32;
        for &k in &vocabulary.leaf_sizes {
            leaf_start.push(start);
            start += k;
        }
        leaf_start.push(start);

        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for l in landmarks {
            for k in 0..2 {
                lo[k] = lo[k].min(l.world_m[k]);
                hi[k] = hi[k].max(l.world_m[k]);
            }
        }
        if n == 0 {
            (lo, hi) = ([0.0; 2], [0.0; 2]);
        }
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(0.0);
        let cell_m = CELL_M.max(extent / (MAX_CELLS as f32).sqrt());
        let nx = ((hi[0] - lo[0]) / cell_m) as usize + 1;
        let ny = ((hi[1] - lo[1]) / cell_m) as usize + 1;
        let cell_of = |l: &Landmark| {
            let cx = (((l.world_m[0] - lo[0]) / cell_m) as usize).min(nx - 1);
            let cy = (((l.world_m[1] - lo[1]) / cell_m) as usize).min(ny - 1);
            cy * nx + cx
        };
        let n_leaves = vocabulary.leaves.len();
        let mut block_m = block_m.max(cell_m);
        let (block_nx, block_ny) = loop {
            let bx = ((hi[0] - lo[0]) / block_m) as usize + 1;
            let by = ((hi[1] - lo[1]) / block_m) as usize + 1;
            if n_leaves * (bx * by + 1) <= MAX_LEAF_BLOCKS || bx * by == 1 {
                break (bx, by);
            }
            block_m *= 1.5;
        };
        let n_blocks = block_nx * block_ny;
        let block_of = |l: &Landmark| {
            let bx = (((l.world_m[0] - lo[0]) / block_m) as usize).min(block_nx - 1);
            let by = (((l.world_m[1] - lo[1]) / block_m) as usize).min(block_ny - 1);
            by * block_nx + bx
        };
        // Within each leaf, the landmarks ordered by block (stable).
        let mut original: Vec<u32> = (0..n as u32).collect();
        let mut leaf_block_start = vec![0u32; n_leaves * (n_blocks + 1)];
        for l in 0..n_leaves {
            let (a, b) = (leaf_start[l] as usize, leaf_start[l + 1] as usize);
            let slice = &mut original[a..b];
            slice.sort_by_key(|&i| block_of(&landmarks[i as usize]));
            let row = &mut leaf_block_start[l * (n_blocks + 1)..(l + 1) * (n_blocks + 1)];
            let mut p = a;
            for (block, start) in row.iter_mut().enumerate() {
                while p < b && block_of(&landmarks[original[p] as usize]) < block {
                    p += 1;
                }
                *start = p as u32;
            }
        }
        let mut cell_start = vec![0u32; nx * ny + 1];
        for l in landmarks {
            cell_start[cell_of(l) + 1] += 1;
        }
        for c in 1..cell_start.len() {
            cell_start[c] += cell_start[c - 1];
        }
        let mut fill = cell_start.clone();
        let mut cell_landmarks = vec![0u32; n];
        for (p, &i) in original.iter().enumerate() {
            let c = cell_of(&landmarks[i as usize]);
            cell_landmarks[fill[c] as usize] = p as u32;
            fill[c] += 1;
        }
        Self {
            descriptors: original
                .iter()
                .map(|&i| landmarks[i as usize].descriptor)
                .collect(),
            original,
            vocabulary,
            word_first_leaf,
            leaf_start,
            origin_m: lo,
            cell_m,
            nx,
            ny,
            cell_start,
            cell_landmarks,
            block_m,
            block_nx,
            block_ny,
            leaf_block_start,
            near_runs: Vec::with_capacity(block_ny),
            probe_pairs: Vec::with_capacity(PREALLOCATED_QUERIES * MAX_PROBED_LEAVES),
            near_descriptors: Vec::with_capacity(n),
            near_indices: Vec::with_capacity(n),
            near_mark: vec![0; n],
            epoch: 0,
            probes: Probes::default(),
            near_probes: NEAR_PROBES,
            comparisons: 0,
        }
    }

    /// Number of landmarks.
    pub fn len(&self) -> usize {
        self.descriptors.len()
    }

    /// True when there is none.
    pub fn is_empty(&self) -> bool {
        self.descriptors.is_empty()
    }

    /// Sets how far the whole-map search descends (clamped to the limits).
    pub fn set_probes(&mut self, probes: Probes) {
        self.probes = Probes {
            words: probes.words.clamp(1, MAX_WORDS),
            leaves: probes.leaves.clamp(1, MAX_PROBED_LEAVES),
        };
    }

    /// The whole-map search's probes.
    pub fn probes(&self) -> Probes {
        self.probes
    }

    /// Descriptor comparisons of the last search (vocabulary nodes
    /// included).
    pub fn comparisons(&self) -> u64 {
        self.comparisons
    }

    /// Best two among every landmark: the reference the searches are
    /// measured against (not counted in [`Self::comparisons`]).
    pub fn best_two_all(&self, queries: &[Descriptor], out: &mut [BestTwo]) {
        best_two_batch(queries, &self.descriptors, out);
        for o in out.iter_mut() {
            o.1 = self.original_of(Some(o.1));
            o.3 = self.original_of(Some(o.3));
        }
    }

    /// The database index of the landmark at `position` (`u32::MAX` for
    /// none).
    fn original_of(&self, position: Option<u32>) -> u32 {
        position
            .and_then(|p| self.original.get(p as usize))
            .copied()
            .unwrap_or(u32::MAX)
    }

    /// Best two among the landmarks in the cells within `reach_m` of
    /// `center_m` (horizontally), gathered outward from it; gives how many
    /// landmarks were searched.
    pub fn best_two_near(
        &mut self,
        queries: &[Descriptor],
        center_m: [f32; 2],
        reach_m: f32,
        out: &mut [BestTwo],
    ) -> usize {
        self.near_descriptors.clear();
        self.near_indices.clear();
        let cell = self.cell_m;
        let fx = (center_m[0] - self.origin_m[0]) / cell;
        let fy = (center_m[1] - self.origin_m[1]) / cell;
        let rings = (reach_m / cell).ceil().max(0.0) as i64 + 1;
        let (cx, cy) = (fx.floor() as i64, fy.floor() as i64);
        for ring in 0..=rings {
            for dy in -ring..=ring {
                let row = cy + dy;
                if row < 0 || row >= self.ny as i64 {
                    continue;
                }
                let step = if dy.abs() == ring { 1 } else { 2 * ring.max(1) };
                let mut dx = -ring;
                while dx <= ring {
                    let col = cx + dx;
                    dx += step;
                    if col < 0 || col >= self.nx as i64 {
                        continue;
                    }
                    // Distance from the center to the nearest point of the cell.
                    let gx = (fx - fx.clamp(col as f32, col as f32 + 1.0)) * cell;
                    let gy = (fy - fy.clamp(row as f32, row as f32 + 1.0)) * cell;
                    if gx * gx + gy * gy > reach_m * reach_m {
                        continue;
                    }
                    let c = row as usize * self.nx + col as usize;
                    let (a, b) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
                    self.near_indices
                        .extend_from_slice(&self.cell_landmarks[a..b]);
                }
            }
        }
        let n = queries.len().min(out.len());
        let gathered = self.near_indices.len();
        if gathered > NEAR_EXACT_MAX {
            // Too many to compare with each: the vocabulary, with the
            // landmarks out of reach skipped.
            self.epoch = self.epoch.wrapping_add(1);
            if self.epoch == 0 {
                self.near_mark.iter_mut().for_each(|m| *m = 0);
                self.epoch = 1;
            }
            for &i in &self.near_indices {
                self.near_mark[i as usize] = self.epoch;
            }
            // The runs of blocks that meet the reach, one per block row.
            // A gathered cell's nearest point is within reach, so its
            // landmarks lie within reach plus a cell's diagonal.
            self.near_runs.clear();
            let block = self.block_m;
            let reach_cells_m = reach_m + cell * std::f32::consts::SQRT_2;
            let bfy = (center_m[1] - self.origin_m[1]) / block;
            for row in 0..self.block_ny {
                let gy = (bfy - bfy.clamp(row as f32, row as f32 + 1.0)) * block;
                if gy.abs() > reach_cells_m {
                    continue;
                }
                let half_m = (reach_cells_m * reach_cells_m - gy * gy).max(0.0).sqrt();
                let first = (((center_m[0] - half_m - self.origin_m[0]) / block).floor())
                    .clamp(0.0, (self.block_nx - 1) as f32) as usize;
                let last = (((center_m[0] + half_m - self.origin_m[0]) / block).floor())
                    .clamp(0.0, (self.block_nx - 1) as f32) as usize;
                let base = row * self.block_nx;
                self.near_runs
                    .push(((base + first) as u32, (base + last + 1) as u32));
            }
            let probes = self.near_probes;
            self.vocabulary_search(&queries[..n], &mut out[..n], probes, Some(self.epoch));
            return gathered;
        }
        self.near_descriptors.clear();
        for &i in &self.near_indices {
            self.near_descriptors.push(self.descriptors[i as usize]);
        }
        best_two_batch(&queries[..n], &self.near_descriptors, &mut out[..n]);
        for o in out[..n].iter_mut() {
            o.1 = self.original_of(self.near_indices.get(o.1 as usize).copied());
            o.3 = self.original_of(self.near_indices.get(o.3 as usize).copied());
        }
        self.comparisons = (n * gathered) as u64;
        gathered
    }

    /// Best two among the landmarks of the vocabulary leaves each query
    /// descends to (see the module docs).
    pub fn best_two_everywhere(&mut self, queries: &[Descriptor], out: &mut [BestTwo]) {
        let probes = self.probes;
        self.vocabulary_search(queries, out, probes, None);
    }

    /// The vocabulary search with `probes`; with `near`, only the landmarks
    /// marked with that epoch are compared. Compiled with the popcnt
    /// instruction where the CPU has it (as the brute-force matcher is):
    /// without it, each of the millions of Hamming distances is a
    /// bit-counting sequence several times slower. The result is the same.
    fn vocabulary_search(
        &mut self,
        queries: &[Descriptor],
        out: &mut [BestTwo],
        probes: Probes,
        near: Option<u32>,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("popcnt") {
                // SAFETY: the CPU supports popcnt, checked just above.
                return unsafe { self.vocabulary_search_popcnt(queries, out, probes, near) };
            }
        }
        self.vocabulary_search_scan(queries, out, probes, near);
    }

    /// [`LandmarkIndex::vocabulary_search_scan`] compiled with popcnt.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "popcnt")]
    unsafe fn vocabulary_search_popcnt(
        &mut self,
        queries: &[Descriptor],
        out: &mut [BestTwo],
        probes: Probes,
        near: Option<u32>,
    ) {
        self.vocabulary_search_scan(queries, out, probes, near);
    }

    /// Each query descends the vocabulary to its probed leaves; the
    /// (leaf, query) pairs are then sorted by leaf and every probed leaf
    /// is read once, in memory order, for all the queries that probe it.
    /// Read query after query, the leaves are scattered through the
    /// landmarks and each costs a cache miss; in order they stream.
    #[inline(always)]
    fn vocabulary_search_scan(
        &mut self,
        queries: &[Descriptor],
        out: &mut [BestTwo],
        probes: Probes,
        near: Option<u32>,
    ) {
        let Self {
            descriptors,
            original,
            vocabulary: v,
            word_first_leaf,
            leaf_start,
            block_nx,
            block_ny,
            leaf_block_start,
            near_runs,
            near_mark,
            probe_pairs,
            ..
        } = self;
        let mut comparisons = 0u64;
        probe_pairs.clear();
        for (qi, q) in queries.iter().enumerate() {
            let mut words = [(u32::MAX, 0u32); MAX_WORDS];
            let n_words = nearest_k(
                v.words.iter().map(|w| q.hamming(w)),
                &mut words[..probes.words],
            );
            comparisons += v.words.len() as u64;
            let mut leaves = [(u32::MAX, 0u32); MAX_PROBED_LEAVES];
            let mut n_leaves = 0;
            for &(_, w) in &words[..n_words] {
                let (a, b) = (
                    word_first_leaf[w as usize] as usize,
                    word_first_leaf[w as usize + 1] as usize,
                );
                comparisons += (b - a) as u64;
                for l in a..b {
                    let d = q.hamming(&v.leaves[l]);
                    n_leaves = insert(&mut leaves[..probes.leaves], n_leaves, (d, l as u32));
                }
            }
            probe_pairs.extend(leaves[..n_leaves].iter().map(|&(_, l)| (l, qi as u32)));
        }
        probe_pairs.sort_unstable();
        for o in out.iter_mut() {
            *o = (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
        }
        let n_blocks = *block_nx * *block_ny;
        for group in probe_pairs.chunk_by(|x, y| x.0 == y.0) {
            let l = group[0].0 as usize;
            let (a, b) = (leaf_start[l] as usize, leaf_start[l + 1] as usize);
            let Some(epoch) = near else {
                comparisons += ((b - a) * group.len()) as u64;
                for &(_, qi) in group {
                    let (q, o) = (&queries[qi as usize], &mut out[qi as usize]);
                    let (d0, i0, d1, i1) = best_two(q, &descriptors[a..b]);
                    for (d, i) in [(d0, i0), (d1, i1)] {
                        if i != u32::MAX {
                            *o = merge(*o, d, original[a + i as usize]);
                        }
                    }
                }
                continue;
            };
            let row = l * (n_blocks + 1);
            for &(first, end) in near_runs.iter() {
                let a = leaf_block_start[row + first as usize] as usize;
                let b = leaf_block_start[row + end as usize] as usize;
                for i in a..b {
                    if near_mark[i] != epoch {
                        continue;
                    }
                    comparisons += group.len() as u64;
                    let d_i = &descriptors[i];
                    for &(_, qi) in group {
                        let o = &mut out[qi as usize];
                        *o = merge(*o, queries[qi as usize].hamming(d_i), original[i]);
                    }
                }
            }
        }
        self.comparisons = comparisons;
    }
}

/// Keeps the `slots.len()` smallest of `distances` (with their indices)
/// in `slots`, ascending; gives how many were kept.
#[inline(always)]
fn nearest_k(distances: impl Iterator<Item = u32>, slots: &mut [(u32, u32)]) -> usize {
    let mut n = 0;
    for (i, d) in distances.enumerate() {
        n = insert(slots, n, (d, i as u32));
    }
    n
}

/// Inserts `item` into the ascending `slots[..n]` (dropping the last when
/// full); gives the new count.
#[inline(always)]
fn insert(slots: &mut [(u32, u32)], n: usize, item: (u32, u32)) -> usize {
    let k = slots.len();
    if k == 0 || (n == k && item.0 >= slots[k - 1].0) {
        return n;
    }
    let mut j = if n < k { n } else { k - 1 };
    while j > 0 && slots[j - 1].0 > item.0 {
        slots[j] = slots[j - 1];
        j -= 1;
    }
    slots[j] = item;
    (n + 1).min(k)
}

/// `best` with the match (`d`, `i`) taken in; of equal distances the
/// lower index, so that the order of merging does not change the result.
#[inline(always)]
fn merge(best: BestTwo, d: u32, i: u32) -> BestTwo {
    let (b0, i0, b1, i1) = best;
    if (d, i) < (b0, i0) {
        (d, i, b0, i0)
    } else if (d, i) < (b1, i1) {
        (b0, i0, d, i)
    } else {
        (b0, i0, b1, i1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// `n` landmarks with random descriptors on a 0.4 m grid, sorted leaf
    /// after leaf of their vocabulary, as a database stores them.
    fn landmarks(n: usize) -> (Vec<Landmark>, Vocabulary) {
        let mut rng = SplitMix64::new(11);
        let raw: Vec<Landmark> = (0..n)
            .map(|i| Landmark {
                world_m: [(i % 50) as f32 * 0.4, (i / 50) as f32 * 0.4, 1.0],
                descriptor: Descriptor(std::array::from_fn(|_| rng.next_u64())),
            })
            .collect();
        crate::reloc::build::organize(raw)
    }

    #[test]
    fn near_search_is_exact_within_the_reach() {
        let (lm, vocabulary) = landmarks(2500);
        let mut index = LandmarkIndex::new(&lm, &vocabulary);
        let queries: Vec<Descriptor> = lm.iter().step_by(97).map(|l| l.descriptor).collect();
        let mut out = vec![(0, 0, 0, 0); queries.len()];
        let center = [10.0, 10.0];
        let searched = index.best_two_near(&queries, center, 3.0, &mut out);
        assert!(searched > 100 && searched < lm.len() / 2, "{searched}");
        for (q, o) in queries.iter().zip(&out) {
            // The brute-force best among the landmarks within the reach
            // (the search may see a little more: whole cells).
            let within =
                |l: &Landmark| (l.world_m[0] - center[0]).hypot(l.world_m[1] - center[1]) <= 3.0;
            let best_within = lm
                .iter()
                .filter(|l| within(l))
                .map(|l| q.hamming(&l.descriptor))
                .min()
                .unwrap_or(u32::MAX);
            assert!(o.0 <= best_within);
            if o.0 == 0 {
                assert_eq!(lm[o.1 as usize].descriptor, *q);
            }
        }
        assert_eq!(index.comparisons(), (queries.len() * searched) as u64);
    }

    #[test]
    fn whole_map_search_finds_near_copies_with_few_comparisons() {
        let (lm, vocabulary) = landmarks(5000);
        let mut index = LandmarkIndex::new(&lm, &vocabulary);
        let mut rng = SplitMix64::new(5);
        // Copies with 10 of 256 bits flipped: far nearer than any other.
        let picks: Vec<usize> = (0..200).map(|_| rng.below(lm.len())).collect();
        let queries: Vec<Descriptor> = picks
            .iter()
            .map(|&i| {
                let mut d = lm[i].descriptor;
                for _ in 0..10 {
                    let b = rng.below(256);
                    d.0[b / 64] ^= 1 << (b % 64);
                }
                d
            })
            .collect();
        let mut out = vec![(0, 0, 0, 0); queries.len()];
        index.best_two_everywhere(&queries, &mut out);
        let found = picks
            .iter()
            .zip(&out)
            .filter(|(&i, o)| o.1 as usize == i)
            .count();
        assert!(found >= 190, "found {found} of 200");
        let per_query = index.comparisons() / queries.len() as u64;
        assert!(
            per_query < lm.len() as u64 / 4,
            "{per_query} comparisons each"
        );
        let mut all = vec![(0, 0, 0, 0); queries.len()];
        index.best_two_all(&queries, &mut all);
        for (o, a) in out.iter().zip(&all) {
            assert!(o.0 >= a.0);
        }
    }

    #[test]
    fn many_landmarks_within_reach_go_through_the_vocabulary_and_stay_in_reach() {
        let (lm, vocabulary) = landmarks(40_000);
        let mut index = LandmarkIndex::new(&lm, &vocabulary);
        let (center, reach) = ([10.0, 100.0], 70.0);
        let within =
            |l: &Landmark| (l.world_m[0] - center[0]).hypot(l.world_m[1] - center[1]) <= reach;
        // Exact copies of landmarks in reach, and of some out of reach.
        let inside: Vec<usize> = (0..lm.len())
            .filter(|&i| within(&lm[i]))
            .step_by(61)
            .collect();
        let outside: Vec<usize> = (0..lm.len())
            .filter(|&i| !within(&lm[i]))
            .step_by(401)
            .collect();
        let queries: Vec<Descriptor> = inside
            .iter()
            .chain(&outside)
            .map(|&i| lm[i].descriptor)
            .collect();
        let mut out = vec![(0, 0, 0, 0); queries.len()];
        let gathered = index.best_two_near(&queries, center, reach, &mut out);
        assert!(gathered > NEAR_EXACT_MAX, "{gathered}");
        assert!(index.comparisons() < (queries.len() * gathered / 10) as u64);
        for (k, o) in out.iter().enumerate() {
            if k < inside.len() {
                assert_eq!((o.0, o.1 as usize), (0, inside[k]));
            }
            // Whatever is found lies within reach (up to whole cells).
            if let Some(l) = lm.get(o.1 as usize) {
                let d = (l.world_m[0] - center[0]).hypot(l.world_m[1] - center[1]);
                assert!(d <= reach + 1.5, "{d}");
            }
        }
    }

    #[test]
    fn reading_only_the_blocks_within_reach_finds_what_reading_whole_leaves_finds() {
        let (lm, vocabulary) = landmarks(40_000);
        let mut blocked = LandmarkIndex::new(&lm, &vocabulary);
        let mut whole = LandmarkIndex::with_block(&lm, &vocabulary, f32::INFINITY);
        assert!(blocked.block_nx * blocked.block_ny > 1);
        assert_eq!(whole.block_nx * whole.block_ny, 1);
        let mut rng = SplitMix64::new(7);
        // Noisy copies of landmarks anywhere, and random descriptors.
        let queries: Vec<Descriptor> = (0..300)
            .map(|k| {
                if k % 3 == 0 {
                    return Descriptor(std::array::from_fn(|_| rng.next_u64()));
                }
                let mut d = lm[rng.below(lm.len())].descriptor;
                for _ in 0..20 {
                    let b = rng.below(256);
                    d.0[b / 64] ^= 1 << (b % 64);
                }
                d
            })
            .collect();
        let mut a = vec![(0, 0, 0, 0); queries.len()];
        let mut b = vec![(0, 0, 0, 0); queries.len()];
        // Centers inside, at the edge and outside the map; reaches that
        // take the vocabulary path and the exact one.
        for (center, reach) in [
            ([10.0, 100.0], 70.0),
            ([0.0, 0.0], 40.0),
            ([19.6, 319.6], 45.0),
            ([-30.0, 150.0], 50.0),
            ([10.0, 10.0], 3.0),
        ] {
            let ga = blocked.best_two_near(&queries, center, reach, &mut a);
            let gb = whole.best_two_near(&queries, center, reach, &mut b);
            assert_eq!(ga, gb);
            assert_eq!(a, b, "center {center:?}, reach {reach}");
            if ga > NEAR_EXACT_MAX {
                assert!(blocked.comparisons() == whole.comparisons());
            }
        }
        blocked.best_two_everywhere(&queries, &mut a);
        whole.best_two_everywhere(&queries, &mut b);
        assert_eq!(a, b);
        blocked.best_two_all(&queries, &mut a);
        whole.best_two_all(&queries, &mut b);
        assert_eq!(a, b);
    }

    #[test]
    fn without_landmarks_nothing_matches() {
        let mut index = LandmarkIndex::new(&[], &Vocabulary::default());
        let q = [Descriptor::default()];
        let mut out = [(0, 0, 0, 0)];
        index.best_two_everywhere(&q, &mut out);
        assert_eq!(out[0].1, u32::MAX);
        assert_eq!(index.best_two_near(&q, [0.0, 0.0], 5.0, &mut out), 0);
        assert_eq!(out[0].1, u32::MAX);
    }
}
