//! Local keypoint features of relocalization: FAST-9 corners on an image
//! pyramid, each with a 256-bit BRIEF-style descriptor, and the brute-force
//! Hamming matcher that pairs them with the map's landmarks
//! ([`super::landmarks`], ORB-SLAM style: features matched, then PnP).
//!
//! Takes an 8-bit gray image (`&[u8]`, width, height, row stride); gives out
//! [`Keypoint`]s in level-0 pixel coordinates (pixel centers at integers).
//! [`FeatureExtractor`] owns the pyramid, the score map, the candidate lists
//! and the comparison pattern: after [`FeatureExtractor::new`],
//! [`FeatureExtractor::extract`] allocates nothing.
//!
//! The descriptor is upright (no orientation is estimated): the vehicle's
//! roll stays small, and rotation invariance would cost distinctiveness.
//! Scale is covered by the pyramid.

use super::descriptor::Descriptor;
use crate::rng::SplitMix64;

/// Side of the square patch the comparison pairs are drawn in, pixels of
/// the keypoint's level.
pub const PATCH_SIZE: usize = 31;
const PATCH_HALF: usize = PATCH_SIZE / 2;
/// Radius of the box blur (5x5) the comparisons are made on.
const BLUR_RADIUS: usize = 2;
/// Pixels skipped at each level's border: the patch and its blur fit inside.
pub const EDGE_PX: usize = PATCH_HALF + BLUR_RADIUS;
/// Seed of the comparison pattern. Landmark databases store descriptors:
/// changing it (or the pattern's drawing) invalidates them.
pub const PATTERN_SEED: u64 = 0x5354_4152_4645_4154;
/// Most pyramid levels; [`FeatureParams::levels`] is clamped to this.
pub const MAX_LEVELS: usize = 8;
/// The Bresenham circle of radius 3 (dx, dy), clockwise from the top.
#[rustfmt::skip]
const CIRCLE: [(isize, isize); 16] = [
    (0, -3), (1, -3), (2, -2), (3, -1), (3, 0), (3, 1), (2, 2), (1, 3),
    (0, 3), (-1, 3), (-2, 2), (-3, 1), (-3, 0), (-3, -1), (-2, -2), (-1, -3),
];

/// A corner with its descriptor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Column in level-0 pixels (pixel centers at integers).
    pub x_px: f32,
    /// Row in level-0 pixels (pixel centers at integers).
    pub y_px: f32,
    /// Pyramid level it was found on (0: full resolution).
    pub level: u8,
    /// FAST score (Rosten): the sum of the circle pixels' differences to the
    /// center beyond the threshold, on the brighter or the darker side.
    pub score: f32,
    /// 256 comparisons on the level's smoothed image.
    pub descriptor: Descriptor,
}

/// Settings of [`FeatureExtractor`].
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureParams {
    /// Most keypoints per image, over all levels.
    pub max_features: usize,
    /// FAST threshold: a circle pixel counts when brighter or darker than
    /// the center by more than this (gray levels).
    pub fast_threshold: u8,
    /// Pyramid levels, level 0 included (clamped to `1..=MAX_LEVELS`).
    pub levels: usize,
    /// Each level is the previous one shrunk by this (clamped to `1.05..=4`).
    pub scale_factor: f32,
    /// Side of the selection grid's cells, pixels of each level: the best
    /// corner of every cell is taken first, so features spread out.
    pub grid_cell_px: usize,
}

impl Default for FeatureParams {
    fn default() -> Self {
        Self {
            max_features: 500,
            fast_threshold: 20,
            levels: 4,
            scale_factor: 1.4,
            grid_cell_px: 32,
        }
    }
}

/// A corner after non-maximum suppression, in level pixels.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    x: u32,
    y: u32,
    score: u16,
    picked: bool,
}

/// One pyramid level: its image, its smoothed image (5x5 box sums) and the
/// pattern's offsets for its row pitch.
#[derive(Debug, Clone)]
struct Level {
    /// Row pitch of `image` and `smooth` (the level's width at capacity).
    stride: usize,
    w: usize,
    h: usize,
    image: Vec<u8>,
    smooth: Vec<u16>,
    /// Horizontal taps into the previous level ([`tap`]).
    taps: Vec<(usize, u32)>,
    circle: [isize; 16],
    pairs: Vec<(isize, isize)>,
}

/// Detects and describes keypoints; owns every buffer.
///
/// Sized in [`Self::new`] for one image size: a larger image given to
/// [`Self::extract`] is cropped to its top-left part of that size.
#[derive(Clone)]
pub struct FeatureExtractor {
    params: FeatureParams,
    levels: Vec<Level>,
    /// FAST scores (0: no corner), level-0 capacity, each level's stride.
    scores: Vec<u16>,
    /// Horizontal 5-pixel sums of the blur.
    row_sums: Vec<u16>,
    candidates: Vec<Candidate>,
    cell_taken: Vec<bool>,
    keypoints: Vec<Keypoint>,
}

impl std::fmt::Debug for FeatureExtractor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FeatureExtractor")
            .field("params", &self.params)
            .finish_non_exhaustive()
    }
}

/// Size of the next level: the previous one shrunk by `scale`.
fn shrink(n: usize, scale: f32) -> usize {
    (n as f32 / scale) as usize
}

impl FeatureExtractor {
    /// An extractor for images of `width x height`; allocates all buffers
    /// and draws the comparison pattern (seed [`PATTERN_SEED`]).
    pub fn new(width: usize, height: usize, params: &FeatureParams) -> Self {
        let scale = if params.scale_factor.is_finite() {
            params.scale_factor.clamp(1.05, 4.0)
        } else {
            1.4
        };
        let params = FeatureParams {
            levels: params.levels.clamp(1, MAX_LEVELS),
            scale_factor: scale,
            grid_cell_px: params.grid_cell_px.max(1),
            ..params.clone()
        };
        let pattern = draw_pattern();
        let (mut w, mut h) = (width, height);
        let mut levels = Vec::with_capacity(params.levels);
        for l in 0..params.levels {
            if l > 0 {
                (w, h) = (shrink(w, scale), shrink(h, scale));
            }
            let at = |dx: isize, dy: isize| dy * w as isize + dx;
            levels.push(Level {
                stride: w,
                w: 0,
                h: 0,
                image: vec![0; w * h],
                smooth: vec![0; w * h],
                taps: (0..w).map(|x| tap(x, scale)).collect(),
                circle: CIRCLE.map(|(dx, dy)| at(dx, dy)),
                pairs: pattern
                    .iter()
                    .map(|&[ax, ay, bx, by]| (at(ax, ay), at(bx, by)))
                    .collect(),
            });
        }
        let cell = params.grid_cell_px;
        Self {
            scores: vec![0; width * height],
            row_sums: vec![0; width * height],
            // Suppressed maxima are never 8-adjacent: at most one per 2x2.
            candidates: Vec::with_capacity(width.div_ceil(2) * height.div_ceil(2)),
            cell_taken: vec![false; width.div_ceil(cell) * height.div_ceil(cell)],
            keypoints: Vec::with_capacity(params.max_features.min(width * height)),
            levels,
            params,
        }
    }

    /// The settings in use (after clamping).
    pub fn params(&self) -> &FeatureParams {
        &self.params
    }

    /// Keypoints of an 8-bit gray image, `stride` bytes per row, best first
    /// within each level, levels in order. Empty when the image is invalid
    /// (`stride < width`, `pixels` too short) or smaller than the patch.
    /// An image larger than the size given to [`Self::new`] is cropped to its
    /// top-left part of that size. Allocates nothing.
    pub fn extract(
        &mut self,
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
    ) -> &[Keypoint] {
        self.keypoints.clear();
        let needed = height
            .checked_sub(1)
            .and_then(|r| r.checked_mul(stride))
            .and_then(|n| n.checked_add(width));
        if stride < width || needed.is_none_or(|n| pixels.len() < n) {
            return &self.keypoints;
        }
        let scale = self.params.scale_factor;
        let cap_h = self.levels[0].image.len() / self.levels[0].stride.max(1);
        let (w, h) = (width.min(self.levels[0].stride), height.min(cap_h));
        let l0 = &mut self.levels[0];
        (l0.w, l0.h) = (w, h);
        for y in 0..h {
            l0.image[y * l0.stride..][..w].copy_from_slice(&pixels[y * stride..][..w]);
        }
        // Usable levels: those the patch fits in.
        let min_side = 2 * EDGE_PX + 1;
        let mut usable = 0;
        for l in 0..self.levels.len() {
            if l > 0 {
                let (done, rest) = self.levels.split_at_mut(l);
                downscale(&done[l - 1], &mut rest[0], scale);
            }
            if self.levels[l].w < min_side || self.levels[l].h < min_side {
                break;
            }
            usable = l + 1;
        }
        // ORB's split of the budget: proportional to each level's area.
        let f = 1.0 / (scale as f64 * scale as f64);
        let total = self.params.max_features;
        let cumulative = |l: usize| {
            (total as f64 * (1.0 - f.powi(l as i32)) / (1.0 - f.powi(usable as i32))).round()
                as usize
        };
        let mut carry = 0;
        for l in 0..usable {
            let budget = if l + 1 == usable {
                total - self.keypoints.len()
            } else {
                cumulative(l + 1) - cumulative(l) + carry
            };
            let level = &mut self.levels[l];
            let (t, cell) = (self.params.fast_threshold, self.params.grid_cell_px);
            detect(level, t, &mut self.scores, &mut self.candidates);
            let n = select(
                &mut self.candidates,
                level.w,
                cell,
                budget,
                &mut self.cell_taken,
            );
            carry = budget - n;
            if n == 0 {
                continue;
            }
            blur(level, &mut self.row_sums);
            let s = scale.powi(l as i32);
            for c in self.candidates.iter().filter(|c| c.picked) {
                let center = c.y as usize * level.stride + c.x as usize;
                self.keypoints.push(Keypoint {
                    x_px: (c.x as f32 + 0.5) * s - 0.5,
                    y_px: (c.y as f32 + 0.5) * s - 0.5,
                    level: l as u8,
                    score: c.score as f32,
                    descriptor: describe(&level.smooth, center, &level.pairs),
                });
            }
        }
        &self.keypoints
    }
}

/// The 256 comparison pairs `[ax, ay, bx, by]`: offsets i.i.d. Gaussian of
/// sigma `PATCH_SIZE / 5`, redrawn outside the patch (BRIEF's G II).
fn draw_pattern() -> Vec<[isize; 4]> {
    let mut rng = SplitMix64::new(PATTERN_SEED);
    let sigma = PATCH_SIZE as f64 / 5.0;
    let half = PATCH_HALF as f64;
    let mut gauss = move || loop {
        // Box-Muller; `1 - u` keeps the logarithm finite.
        let r = (-2.0 * (1.0 - rng.next_f64()).ln()).sqrt();
        let v = (sigma * r * (std::f64::consts::TAU * rng.next_f64()).cos()).round();
        if v.abs() <= half {
            return v as isize;
        }
    };
    let mut pattern = Vec::with_capacity(256);
    while pattern.len() < 256 {
        let p = [gauss(), gauss(), gauss(), gauss()];
        if (p[0], p[1]) != (p[2], p[3]) {
            pattern.push(p);
        }
    }
    pattern
}

/// Bilinear resize of `src` by `1 / scale` into `dst` (sets `dst`'s size).
/// Level pixel `x` samples the previous level at `(x + 0.5) * scale - 0.5`.
fn downscale(src: &Level, dst: &mut Level, scale: f32) {
    (dst.w, dst.h) = (shrink(src.w, scale), shrink(src.h, scale));
    if dst.w == 0 || dst.h == 0 || src.w < 2 || src.h < 2 {
        (dst.w, dst.h) = (0, 0);
        return;
    }
    for y in 0..dst.h {
        let (y0, wy) = tap(y, scale);
        let y0 = y0.min(src.h - 2);
        let r0 = &src.image[y0 * src.stride..][..src.w];
        let r1 = &src.image[(y0 + 1) * src.stride..][..src.w];
        let out = &mut dst.image[y * dst.stride..][..dst.w];
        for (o, &(x0, wx)) in out.iter_mut().zip(&dst.taps) {
            let x0 = x0.min(src.w - 2);
            let top = r0[x0] as u32 * (256 - wx) + r0[x0 + 1] as u32 * wx;
            let bottom = r1[x0] as u32 * (256 - wx) + r1[x0 + 1] as u32 * wx;
            *o = ((top * (256 - wy) + bottom * wy + (1 << 15)) >> 16) as u8;
        }
    }
}

/// Where pixel `i` of a level samples the previous one: index and 8-bit
/// fixed-point weight of the next pixel. With `scale > 1` the sample stays
/// below the last source pixel (the callers' clamps only guard rounding).
fn tap(i: usize, scale: f32) -> (usize, u32) {
    let p = ((i as f32 + 0.5) * scale - 0.5).max(0.0);
    let i0 = p as usize;
    (i0, ((p - i0 as f32).min(1.0) * 256.0) as u32)
}

/// Pixels scored together by [`score_row`].
const LANES: usize = 32;

/// FAST-9 scores of the `n` pixels from index `start` of `img` into `out`:
/// 0 when not a corner (no 9 contiguous circle pixels all brighter, or all
/// darker, than the center by more than `t`), else Rosten's score: the sum
/// of the differences beyond `t` over the brighter circle pixels or over
/// the darker ones, whichever is larger (it peaks on the corner pixel, where
/// the smallest difference along the arc is often flat). Branch-free over
/// `LANES` pixels at a time, so it vectorizes.
#[inline(always)]
fn score_row(img: &[u8], start: usize, n: usize, circle: &[isize; 16], t: u8, out: &mut [u16]) {
    for chunk in (0..n).step_by(LANES) {
        // The last chunk overlaps the previous one rather than run short.
        let first = chunk.min(n.saturating_sub(LANES));
        let len = LANES.min(n - first);
        let load = |i: usize| {
            let mut v = [0u8; LANES];
            if len == LANES {
                v.copy_from_slice(&img[i..][..LANES]);
            } else {
                v[..len].copy_from_slice(&img[i..][..len]);
            }
            v
        };
        let i = start + first;
        let mut ring = [[0u8; LANES]; 16];
        for (r, &o) in ring.iter_mut().zip(circle) {
            *r = load(i.wrapping_add_signed(o));
        }
        let mut scores = [0u16; LANES];
        score_lanes(&load(i), &ring, t, &mut scores);
        out[first..][..len].copy_from_slice(&scores[..len]);
    }
}

/// FAST-9 scores of `LANES` centers `c` with circle pixels `ring` (see
/// [`score_row`]); written so it vectorizes across the lanes.
#[inline(always)]
fn score_lanes(c: &[u8; LANES], ring: &[[u8; LANES]; 16], t: u8, out: &mut [u16; LANES]) {
    for j in 0..LANES {
        // How much brighter (`up`) and darker (`down`) each circle pixel is.
        let (mut up, mut down) = ([0u8; 16], [0u8; 16]);
        for k in 0..16 {
            up[k] = ring[k][j].saturating_sub(c[j]);
            down[k] = c[j].saturating_sub(ring[k][j]);
        }
        let corner = arc9_min(&up).max(arc9_min(&down)) > t;
        let beyond = |v: &[u8; 16]| v.iter().map(|&d| d.saturating_sub(t) as u16).sum::<u16>();
        out[j] = if corner {
            beyond(&up).max(beyond(&down))
        } else {
            0
        };
    }
}

/// The largest over the 16 arcs of 9 of the smallest value on the arc
/// (windows of 2, 4, 8 by doubling, then 9).
#[inline(always)]
fn arc9_min(v: &[u8; 16]) -> u8 {
    let mut w2 = [0u8; 22];
    for k in 0..22 {
        w2[k] = v[k % 16].min(v[(k + 1) % 16]);
    }
    let mut w4 = [0u8; 20];
    for k in 0..20 {
        w4[k] = w2[k].min(w2[k + 2]);
    }
    let mut best = 0;
    for k in 0..16 {
        best = best.max(w4[k].min(w4[k + 4]).min(v[(k + 8) % 16]));
    }
    best
}

/// FAST-9 over the level (scores one pixel beyond the keypoint border, for
/// the suppression), then 3x3 non-maximum suppression into `out` (raster
/// order). Ties go to the earlier pixel in raster order.
fn detect(level: &Level, threshold: u8, scores: &mut [u16], out: &mut Vec<Candidate>) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { detect_avx2(level, threshold, scores, out) };
        }
    }
    detect_scan(level, threshold, scores, out)
}

/// [`detect_scan`] compiled for AVX2 (twice the lanes of the baseline SSE2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn detect_avx2(level: &Level, threshold: u8, scores: &mut [u16], out: &mut Vec<Candidate>) {
    detect_scan(level, threshold, scores, out)
}

#[inline(always)]
fn detect_scan(level: &Level, threshold: u8, scores: &mut [u16], out: &mut Vec<Candidate>) {
    out.clear();
    let (w, h, s, img) = (level.w, level.h, level.stride, &level.image[..]);
    let (x0, x1) = (EDGE_PX - 1, w - EDGE_PX + 1);
    let n = x1 - x0;
    for y in EDGE_PX - 1..h - EDGE_PX + 1 {
        let row = y * s + x0;
        score_row(
            img,
            row,
            n,
            &level.circle,
            threshold,
            &mut scores[row..][..n],
        );
    }
    // Suppression, branch-free over `LANES` pixels, then the rare maxima.
    let n = w - 2 * EDGE_PX;
    for y in EDGE_PX..h - EDGE_PX {
        for chunk in (0..n).step_by(LANES) {
            // As in `score_row`: the last chunk overlaps the previous one.
            let first = chunk.min(n.saturating_sub(LANES));
            let len = LANES.min(n - first);
            let row = |y: usize| {
                let mut v = [0u16; LANES + 2];
                let i = y * s + EDGE_PX - 1 + first;
                if len == LANES {
                    v.copy_from_slice(&scores[i..][..LANES + 2]);
                } else {
                    v[..len + 2].copy_from_slice(&scores[i..][..len + 2]);
                }
                v
            };
            let (up, mid, down) = (row(y - 1), row(y), row(y + 1));
            let mut keep = [false; LANES];
            for j in 0..LANES {
                let earlier = up[j].max(up[j + 1]).max(up[j + 2]).max(mid[j]);
                let later = down[j].max(down[j + 1]).max(down[j + 2]).max(mid[j + 2]);
                keep[j] = (mid[j + 1] > earlier) & (mid[j + 1] >= later);
            }
            for (j, _) in keep
                .iter()
                .enumerate()
                .filter(|&(j, &k)| k && first + j >= chunk)
            {
                if out.len() < out.capacity() {
                    out.push(Candidate {
                        x: (first + j + EDGE_PX) as u32,
                        y: y as u32,
                        score: mid[j + 1],
                        picked: false,
                    });
                }
            }
        }
    }
}

/// Picks up to `budget` candidates: by score, the best of each grid cell
/// first, then the best of the rest. Sorts `cands` by score (descending,
/// ties in raster order) and marks the picked; returns how many.
fn select(
    cands: &mut [Candidate],
    w: usize,
    cell: usize,
    budget: usize,
    taken: &mut [bool],
) -> usize {
    cands.sort_unstable_by_key(|c| (std::cmp::Reverse(c.score), c.y, c.x));
    let cells_x = w.div_ceil(cell);
    taken.fill(false);
    let mut n = 0;
    for c in cands.iter_mut() {
        if n == budget {
            return n;
        }
        let id = (c.y as usize / cell) * cells_x + c.x as usize / cell;
        if let Some(t) = taken.get_mut(id).filter(|t| !**t) {
            (*t, c.picked) = (true, true);
            n += 1;
        }
    }
    for c in cands.iter_mut().filter(|c| !c.picked) {
        if n == budget {
            break;
        }
        c.picked = true;
        n += 1;
    }
    n
}

/// 5x5 box sums of the level's interior (2 pixels in from each border; the
/// patches never read closer), into `level.smooth`.
fn blur(level: &mut Level, row_sums: &mut [u16]) {
    let (w, h, s) = (level.w, level.h, level.stride);
    let n = w - 2 * BLUR_RADIUS;
    for y in 0..h {
        let r = &level.image[y * s..][..w];
        let (a, b, c, d, e) = (
            &r[..n],
            &r[1..][..n],
            &r[2..][..n],
            &r[3..][..n],
            &r[4..][..n],
        );
        for (k, o) in row_sums[y * s + 2..][..n].iter_mut().enumerate() {
            *o = a[k] as u16 + b[k] as u16 + c[k] as u16 + d[k] as u16 + e[k] as u16;
        }
    }
    for y in BLUR_RADIUS..h - BLUR_RADIUS {
        let at = |dy: usize| &row_sums[(y + dy - 2) * s + 2..][..n];
        let (a, b, c, d, e) = (at(0), at(1), at(2), at(3), at(4));
        for (k, o) in level.smooth[y * s + 2..][..n].iter_mut().enumerate() {
            *o = a[k] + b[k] + c[k] + d[k] + e[k];
        }
    }
}

/// The descriptor at `center` of a smoothed level: bit i is set when the
/// first pixel of pair i is darker than the second.
fn describe(smooth: &[u16], center: usize, pairs: &[(isize, isize)]) -> Descriptor {
    let mut bits = [0u64; 4];
    for (word, chunk) in bits.iter_mut().zip(pairs.chunks_exact(64)) {
        for (j, &(a, b)) in chunk.iter().enumerate() {
            let (pa, pb) = (
                smooth[center.wrapping_add_signed(a)],
                smooth[center.wrapping_add_signed(b)],
            );
            *word |= ((pa < pb) as u64) << j;
        }
    }
    Descriptor(bits)
}

/// For a query descriptor, the best and second-best training descriptors by
/// Hamming distance: `(best distance, best index, second distance, second
/// index)`; ties go to the lower index. Missing entries (fewer than two
/// training descriptors) are `u32::MAX`. Uses AVX2 / popcnt where the CPU
/// has them.
pub fn best_two(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            // SAFETY: the CPU supports both features, checked just above.
            return unsafe { best_two_avx2(query, train) };
        }
        if std::arch::is_x86_feature_detected!("popcnt") {
            // SAFETY: the CPU supports popcnt, checked just above.
            return unsafe { best_two_popcnt(query, train) };
        }
    }
    best_two_scan(query, train)
}

/// [`best_two_scan`] compiled for AVX2 and popcnt.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn best_two_avx2(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    best_two_scan(query, train)
}

/// [`best_two_scan`] compiled with the popcnt instruction.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
unsafe fn best_two_popcnt(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    best_two_scan(query, train)
}

/// The scan: one pass, the rare updates behind one well-predicted branch.
/// With AVX2 each distance is a handful of vector instructions (xor, nibble
/// table popcount, horizontal sum); with popcnt, four `popcnt`s.
#[inline(always)]
fn best_two_scan(query: &Descriptor, train: &[Descriptor]) -> (u32, u32, u32, u32) {
    let (mut best, mut best_i, mut second, mut second_i) = (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
    for (i, t) in train.iter().enumerate() {
        let d = query.hamming(t);
        if d < second {
            if d < best {
                (second, second_i, best, best_i) = (best, best_i, d, i as u32);
            } else {
                (second, second_i) = (d, i as u32);
            }
        }
    }
    (best, best_i, second, second_i)
}

/// Queries matched per pass over the training set by [`best_two_batch`].
pub const BATCH: usize = 8;

/// [`best_two`] for every descriptor of `queries`, into `out` (one entry
/// per query; extra queries beyond `out.len()` are skipped). Matches
/// [`BATCH`] queries per pass over `train`, so the training set streams
/// through the cache once per batch rather than once per query.
pub fn best_two_batch(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            // SAFETY: the CPU supports both features, checked just above.
            return unsafe { best_two_batch_avx2(queries, train, out) };
        }
        if std::arch::is_x86_feature_detected!("popcnt") {
            // SAFETY: the CPU supports popcnt, checked just above.
            return unsafe { best_two_batch_popcnt(queries, train, out) };
        }
    }
    best_two_batch_scan(queries, train, out)
}

/// [`best_two_batch_scan`] compiled for AVX2 and popcnt.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn best_two_batch_avx2(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    best_two_batch_scan(queries, train, out)
}

/// [`best_two_batch_scan`] compiled with the popcnt instruction.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
unsafe fn best_two_batch_popcnt(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    best_two_batch_scan(queries, train, out)
}

#[inline(always)]
fn best_two_batch_scan(
    queries: &[Descriptor],
    train: &[Descriptor],
    out: &mut [(u32, u32, u32, u32)],
) {
    let n = queries.len().min(out.len());
    for (qs, os) in queries[..n].chunks(BATCH).zip(out[..n].chunks_mut(BATCH)) {
        let mut q = [Descriptor::default(); BATCH];
        q[..qs.len()].copy_from_slice(qs);
        let mut state = [(u32::MAX, u32::MAX, u32::MAX, u32::MAX); BATCH];
        for (i, t) in train.iter().enumerate() {
            let mut d = [0u32; BATCH];
            for j in 0..BATCH {
                d[j] = q[j].hamming(t);
            }
            for j in 0..BATCH {
                let s = &mut state[j];
                if d[j] < s.2 {
                    if d[j] < s.0 {
                        *s = (d[j], i as u32, s.0, s.1);
                    } else {
                        s.2 = d[j];
                        s.3 = i as u32;
                    }
                }
            }
        }
        os.copy_from_slice(&state[..os.len()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batch_matching_agrees_with_one_at_a_time() {
        let mut rng = crate::rng::SplitMix64::new(7);
        let mut draw = || Descriptor(std::array::from_fn(|_| rng.next_u64()));
        let train: Vec<Descriptor> = (0..1000).map(|_| draw()).collect();
        let queries: Vec<Descriptor> = (0..21).map(|_| draw()).collect();
        let mut out = vec![(0, 0, 0, 0); 21];
        best_two_batch(&queries, &train, &mut out);
        for (q, o) in queries.iter().zip(&out) {
            assert_eq!(*o, best_two(q, &train));
        }
    }

    /// Value noise (octaves of 16, 8 and 4 px, smoothstep), contrast
    /// stretched with saturation, at `(x, y)` pixels.
    fn noise(x: f32, y: f32) -> f32 {
        let mut v = 0.0;
        for (o, cell) in [16.0f32, 8.0, 4.0].into_iter().enumerate() {
            let (fx, fy) = (x / cell, y / cell);
            let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
            let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
            let (tx, ty) = (smooth(fx - fx.floor()), smooth(fy - fy.floor()));
            let at = |dx: i64, dy: i64| {
                let h = ((ix + dx) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    ^ ((iy + dy) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
                SplitMix64::new(h ^ o as u64).next_f64() as f32
            };
            let top = at(0, 0) * (1.0 - tx) + at(1, 0) * tx;
            let bottom = at(0, 1) * (1.0 - tx) + at(1, 1) * tx;
            v += (top * (1.0 - ty) + bottom * ty) / (1 << o) as f32;
        }
        (128.0 + 400.0 * (v / 1.75 - 0.5)).clamp(0.0, 255.0)
    }

    /// A `w x h` camera image of `noise` seen with pixels `scale` wide:
    /// each pixel averages 3x3 samples of its footprint.
    fn render(w: usize, h: usize, scale: f32, dx: f32, dy: f32) -> Vec<u8> {
        let at = |x: f32, y: f32| {
            let sub = |i: usize| (i as f32 - 1.0) / 3.0;
            let sum: f32 = (0..9)
                .map(|i| noise((x + sub(i % 3)) * scale - dx, (y + sub(i / 3)) * scale - dy))
                .sum();
            (sum / 9.0).round() as u8
        };
        (0..w * h)
            .map(|i| at((i % w) as f32 + 0.5, (i / w) as f32 + 0.5))
            .collect()
    }

    fn median(mut v: Vec<u32>) -> u32 {
        v.sort_unstable();
        v.get(v.len() / 2).copied().unwrap_or(u32::MAX)
    }

    #[test]
    fn corners_of_bright_squares_are_found() {
        let (w, h) = (640, 512);
        let mut rng = SplitMix64::new(7);
        let mut squares: Vec<(usize, usize, usize)> = Vec::new();
        while squares.len() < 40 {
            let side = 16 + rng.below(33);
            let (x, y) = (20 + rng.below(w - 40 - side), 20 + rng.below(h - 40 - side));
            let apart = |&(qx, qy, qs): &(usize, usize, usize)| {
                x > qx + qs + 8 || qx > x + side + 8 || y > qy + qs + 8 || qy > y + side + 8
            };
            if squares.iter().all(apart) {
                squares.push((x, y, side));
            }
        }
        let mut img = vec![20u8; w * h];
        let mut corners = Vec::new();
        for &(x, y, s) in &squares {
            for row in img[y * w..(y + s) * w].chunks_exact_mut(w) {
                row[x..x + s].fill(200);
            }
            let (a, b, c, d) = (x as f32, (x + s - 1) as f32, y as f32, (y + s - 1) as f32);
            corners.extend([(a, c), (b, c), (a, d), (b, d)]);
        }
        let dist = |k: &Keypoint, &(cx, cy): &(f32, f32)| (k.x_px - cx).hypot(k.y_px - cy);
        let mut fx = FeatureExtractor::new(w, h, &FeatureParams::default());
        let kps = fx.extract(&img, w, h, w);
        assert!(!kps.is_empty());
        for k in kps {
            let near = corners.iter().map(|c| dist(k, c)).fold(f32::MAX, f32::min);
            // A pixel of the level, and the blur of the downscaling.
            let tol = 1.5 + 2.0 * 1.4f32.powi(k.level as i32);
            assert!(near <= tol, "keypoint {k:?} is {near} px from any corner");
        }
        let found = corners
            .iter()
            .filter(|c| kps.iter().any(|k| k.level == 0 && dist(k, c) <= 1.0))
            .count();
        println!(
            "squares: {} keypoints, {found} of 160 corners at level 0",
            kps.len()
        );
        assert!(found >= 150, "{found} of 160 corners");
    }

    #[test]
    fn shifted_texture_gives_shifted_matching_keypoints() {
        let (w, h, dx, dy) = (640, 512, 7.0, -5.0);
        let (a, b) = (render(w, h, 1.0, 0.0, 0.0), render(w, h, 1.0, dx, dy));
        let mut fx = FeatureExtractor::new(w, h, &FeatureParams::default());
        let ka = fx.extract(&a, w, h, w).to_vec();
        let kb = fx.extract(&b, w, h, w);
        assert!(ka.len() > 400, "{} keypoints", ka.len());
        let mut dists = Vec::new();
        for k in kb {
            // One pixel of the level: its sampling phase moved.
            let tol = 1.4f32.powi(k.level as i32) + 0.01;
            let same = |q: &&Keypoint| {
                q.level == k.level
                    && (q.x_px + dx - k.x_px).abs() <= tol
                    && (q.y_px + dy - k.y_px).abs() <= tol
            };
            if let Some(q) = ka.iter().find(same) {
                dists.push(q.descriptor.hamming(&k.descriptor));
            }
        }
        let (n, med) = (dists.len(), median(dists));
        println!(
            "shift: {n} of {} found again, median Hamming {med}",
            kb.len()
        );
        assert!(n * 2 >= kb.len(), "{n} of {}", kb.len());
        assert!(med <= 10, "median Hamming {med}");
    }

    #[test]
    fn scaled_texture_matches_across_levels() {
        let (s, w, h) = (1.4f32, 640, 512);
        let (ws, hs) = (shrink(w, s), shrink(h, s));
        let params = FeatureParams::default();
        let a = render(w, h, 1.0, 0.0, 0.0);
        // Off by a fraction of a pixel too: another sampling phase.
        let b = render(ws, hs, s, 0.37, 0.61);
        let ka = FeatureExtractor::new(w, h, &params)
            .extract(&a, w, h, w)
            .to_vec();
        let kb = FeatureExtractor::new(ws, hs, &params)
            .extract(&b, ws, hs, ws)
            .to_vec();
        // Level 1 of the near view sees what level 0 of the far view sees.
        let ka: Vec<Keypoint> = ka.into_iter().filter(|k| k.level == 1).collect();
        let kb: Vec<Keypoint> = kb.into_iter().filter(|k| k.level == 0).collect();
        let (da, db): (Vec<_>, Vec<_>) = (
            ka.iter().map(|k| k.descriptor).collect(),
            kb.iter().map(|k| k.descriptor).collect(),
        );
        let (mut dists, mut placed) = (Vec::new(), 0);
        for (i, k) in ka.iter().enumerate() {
            let (d, j, _, _) = best_two(&k.descriptor, &db);
            let q = &kb[j as usize];
            if best_two(&q.descriptor, &da).1 as usize == i {
                dists.push(d);
                let (x, y) = ((q.x_px + 0.5) * s - 0.87, (q.y_px + 0.5) * s - 1.11);
                placed += usize::from((k.x_px - x).hypot(k.y_px - y) <= 2.0 * s);
            }
        }
        let unrelated = median(
            da.iter()
                .zip(db.iter().rev())
                .map(|(a, b)| a.hamming(b))
                .collect(),
        );
        let (n, med) = (dists.len(), median(dists));
        println!(
            "scale: unrelated {unrelated}; {n} mutual matches of {} / {}, {placed} in place, median Hamming {med}",
            ka.len(),
            kb.len()
        );
        assert!(n >= 50 && placed * 10 >= n * 8, "{placed} of {n} in place");
        assert!(med <= 40, "median Hamming {med}");
    }

    #[test]
    fn tiny_or_invalid_images_give_no_features() {
        let mut fx = FeatureExtractor::new(64, 48, &FeatureParams::default());
        let img = render(100, 100, 1.0, 0.0, 0.0);
        for (w, h, stride, len) in [
            (8, 8, 8, 64),
            (0, 0, 0, 0),
            (0, 5, 0, 0),
            (40, 40, 30, 10_000),  // stride < width
            (64, 48, 64, 1000),    // too short
            (34, 34, 100, 10_000), // smaller than the patch
            (100, 1, 100, 10_000),
            (1, 100, 1, 10_000),
            (10, 10, usize::MAX, 10_000), // overflowing size
        ] {
            assert!(fx.extract(&img[..len], w, h, stride).is_empty(), "{w}x{h}");
        }
        // Larger than the capacity: the top-left 64 x 48 only.
        let kps = fx.extract(&img, 100, 100, 100);
        assert!(kps.iter().all(|k| k.x_px < 64.0 && k.y_px < 48.0));
        let odd = FeatureParams {
            levels: 0,
            grid_cell_px: 0,
            scale_factor: f32::NAN,
            ..Default::default()
        };
        assert!(FeatureExtractor::new(0, 0, &odd)
            .extract(&img, 100, 100, 100)
            .is_empty());
        assert!(!FeatureExtractor::new(100, 100, &odd)
            .extract(&img, 100, 100, 100)
            .is_empty());
    }

    #[test]
    fn extraction_is_deterministic_and_keeps_its_buffers() {
        let (w, h) = (320, 256);
        let img = render(w, h, 1.3, 0.0, 0.0);
        let params = FeatureParams {
            max_features: 200,
            ..Default::default()
        };
        let mut fx = FeatureExtractor::new(w, h, &params);
        let caps = |f: &FeatureExtractor| {
            let mut c = vec![
                f.scores.capacity(),
                f.row_sums.capacity(),
                f.candidates.capacity(),
            ];
            c.push(f.keypoints.capacity());
            c.extend(
                f.levels
                    .iter()
                    .flat_map(|l| [l.image.capacity(), l.smooth.capacity()]),
            );
            c
        };
        let before = caps(&fx);
        let first = fx.extract(&img, w, h, w).to_vec();
        assert_eq!(first, fx.extract(&img, w, h, w));
        assert_eq!(
            first,
            FeatureExtractor::new(w, h, &params).extract(&img, w, h, w)
        );
        assert_eq!(before, caps(&fx));
        assert!(!first.is_empty() && first.len() <= 200);
        // A padded stride gives the same features.
        let padded: Vec<u8> = img
            .chunks_exact(w)
            .flat_map(|r| [r, &[9; 13]].concat())
            .collect();
        assert_eq!(first, fx.extract(&padded, w, h, w + 13));
    }

    #[test]
    fn best_two_finds_the_two_nearest() {
        let mut rng = SplitMix64::new(3);
        let train: Vec<Descriptor> = (0..1000)
            .map(|_| Descriptor([(); 4].map(|_| rng.next_u64())))
            .collect();
        let mut query = train[617];
        query.0[2] ^= 0b1011;
        let mut by_distance: Vec<(u32, u32)> = train
            .iter()
            .zip(0..)
            .map(|(t, i)| (query.hamming(t), i))
            .collect();
        by_distance.sort_unstable();
        let (d0, i0, d1, i1) = best_two(&query, &train);
        assert_eq!(((d0, i0), (d1, i1)), ((3, 617), by_distance[1]));
        let none = u32::MAX;
        assert_eq!(best_two(&query, &[]), (none, none, none, none));
        assert_eq!(best_two(&query, &train[617..618]), (3, 0, none, none));
        assert_eq!(best_two(&train[5], &[train[5]; 3]), (0, 0, 0, 1));
    }

    /// Prints timings (asserts nothing about time: not a benchmark).
    #[test]
    fn timing_extract_and_best_two() {
        let (w, h) = (640, 512);
        let img = render(w, h, 1.0, 0.0, 0.0);
        let mut fx = FeatureExtractor::new(w, h, &FeatureParams::default());
        let mut times_ms: Vec<f64> = (0..21)
            .map(|_| {
                let t = std::time::Instant::now();
                std::hint::black_box(fx.extract(&img, w, h, w));
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        times_ms.sort_by(f64::total_cmp);
        let n = fx.extract(&img, w, h, w).len();
        println!(
            "extract 640x512: {n} keypoints, median {:.2} ms, min {:.2} ms",
            times_ms[10], times_ms[0]
        );
        let mut rng = SplitMix64::new(11);
        let train: Vec<Descriptor> = (0..100_000)
            .map(|_| Descriptor([(); 4].map(|_| rng.next_u64())))
            .collect();
        let queries = &fx.extract(&img, w, h, w)[..50.min(n)];
        let t = std::time::Instant::now();
        let check: u64 = queries
            .iter()
            .map(|q| best_two(&q.descriptor, &train).0 as u64)
            .sum();
        let secs = t.elapsed().as_secs_f64();
        let per_s = (queries.len() * train.len()) as f64 / secs;
        println!(
            "best_two: {} x {} in {:.1} ms: {:.0} M descriptors/s (check {check})",
            queries.len(),
            train.len(),
            secs * 1e3,
            per_s / 1e6
        );
    }
}
