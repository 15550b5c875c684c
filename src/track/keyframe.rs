//! Keyframe preparation: from a rendered view (gray + metric depth) to the
//! per-level point sets the aligner consumes.
//!
//! Runs once per keyframe on the render thread. For each pyramid level it
//! selects pixels with strong gradient and valid, continuous depth using a
//! block-adaptive threshold (so texture-poor regions still contribute, as in
//! DSO), keeps at most one pixel per grid cell (the strongest), back-projects
//! them to 3D keyframe points and precomputes the inverse-compositional
//! Jacobian of each. All storage is allocated at construction and reused.

use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::ImageF32;
use crate::render::{RenderedView, NO_DEPTH};
use crate::track::TrackerConfig;

use super::pyramid::Pyramid;

/// One selected keyframe pixel.
#[derive(Debug, Clone, Copy, Default)]
pub struct KeyPoint {
    /// The point in the keyframe camera frame, meters.
    pub p_keyframe: [f32; 3],
    /// Rendered intensity at the pixel (0..=255).
    pub gray: f32,
    /// `d I_ref(pi(K exp(delta) p)) / d delta` at `delta = 0`, `delta = [v; w]`.
    pub jacobian: [f32; 6],
}

impl KeyPoint {
    /// The keyframe point at pixel `(x_px, y_px)` with depth `depth_m`,
    /// rendered intensity `gray` and image gradient `(grad_x, grad_y)`
    /// (gray levels per pixel), back-projected through the pinhole
    /// `[fx, fy, cx, cy]`, with its inverse-compositional Jacobian
    /// `J = grad * d pi / d p * [I | -[p]x]`. The one constructor the tracker's
    /// keyframe preparation and relocalization's coarse points share.
    #[inline]
    pub fn from_pixel(
        x_px: f32,
        y_px: f32,
        depth_m: f32,
        gray: f32,
        grad_x: f32,
        grad_y: f32,
        [fx, fy, cx, cy]: [f32; 4],
    ) -> Self {
        let z = depth_m;
        let px = (x_px - cx) / fx * z;
        let py = (y_px - cy) / fy * z;
        let inv_z = 1.0 / z;
        let ru = grad_x * fx * inv_z;
        let rv = grad_y * fy * inv_z;
        let rz = -(grad_x * fx * px + grad_y * fy * py) * inv_z * inv_z;
        // J = r * [I | -[p]x], and r * (-[p]x) = p x r.
        Self {
            p_keyframe: [px, py, z],
            gray,
            jacobian: [
                ru,
                rv,
                rz,
                py * rz - z * rv,
                z * ru - px * rz,
                px * rv - py * ru,
            ],
        }
    }
}

/// Points of one pyramid level.
#[derive(Debug, Clone)]
pub struct KeyframeLevel {
    /// Selected points; capacity fixed at construction.
    pub points: Vec<KeyPoint>,
    /// Pinhole camera of this level.
    pub camera: PinholeCamera,
}

/// A prepared keyframe.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// Increasing id, for logs and statistics.
    pub id: u64,
    /// Pose of the keyframe camera.
    pub world_from_keyframe: Pose,
    /// Capture time of the frame whose pose estimate requested this keyframe.
    pub requested_at_ns: u64,
    /// Median depth of the finest-level points, meters (0 when none).
    pub median_depth_m: f32,
    /// The finest pyramid level the map's appearance supports
    /// ([`gate_level`]): 0 on a map as fine as the camera, 1 where it is
    /// coarser than the camera's pixels at level 0. Relocalization's
    /// verification starts there with `[reloc] gate_at_map_detail`
    /// ([`super::min_correlations_from`]); otherwise, and in tracking's
    /// own correlation check, every gate reads from level 0.
    pub gate_level: usize,
    /// Per level, finest first.
    pub levels: Vec<KeyframeLevel>,
    scratch: PrepScratch,
}

#[derive(Debug, Clone)]
struct PrepScratch {
    gray: Pyramid,
    depth: Vec<ImageF32>,
    grad: ImageF32,
    /// Row-wise 3-pixel depth minimum and maximum (continuity test).
    depth_min3: ImageF32,
    depth_max3: ImageF32,
    hist: Vec<u32>,
    /// Per pixel, 1 where its gradient passes its block's threshold.
    mask: Vec<u8>,
    /// A row of [`count_cells`]' scratch.
    any_row: Vec<u8>,
    /// Selection threshold of each block, row-major.
    thresholds: Vec<f32>,
    depths: Vec<f32>,
}

/// A pyramid level's pixels are as fine as the map when, at the keyframe's
/// median depth, one covers at least this fraction of the map's detail
/// spacing. Measured (docs/building-scale.md, "Gates at the map's
/// detail"): true poses on a map scanned at 1 cm (10.8 mm spacing) pass
/// the gates at level 0 seen from 2.5 m (0.55 of the spacing per pixel);
/// on one scanned at 2 cm (22.8 mm) level 0 (0.26) correlated as poorly as
/// wrong poses in local contrast (0.32-0.63), level 1 (0.52) at
/// 0.70-0.91.
const GATE_PIXEL_PER_DETAIL: f32 = 0.5;

/// The coarsest first level of the gates: they read three levels from it
/// (the pyramid's four levels), and a gate that started coarser would
/// miss the slides of a few centimeters that the finer levels catch.
pub const MAX_GATE_LEVEL: usize = 1;

/// The finest pyramid level whose pixels, at `median_depth_m` through a
/// focal length of `fx` pixels, cover at least half the map's detail
/// spacing `detail_m` (0 for a map as fine as the camera, or no depth),
/// at most [`MAX_GATE_LEVEL`].
pub fn gate_level(detail_m: f32, median_depth_m: f32, fx: f32) -> usize {
    if !(detail_m > 0.0 && median_depth_m > 0.0 && fx > 0.0) {
        return 0;
    }
    let pixel_m = median_depth_m / fx;
    (0..MAX_GATE_LEVEL)
        .find(|&l| pixel_m * (1u32 << l) as f32 >= GATE_PIXEL_PER_DETAIL * detail_m)
        .unwrap_or(MAX_GATE_LEVEL)
}

/// Gradient magnitude histogram range (gray levels per pixel).
const HIST_BINS: usize = 64;
/// Smallest threshold block, pixels.
const MIN_BLOCK_PX: usize = 8;

impl Keyframe {
    /// Allocates a keyframe for `camera` (pinhole, level 0) and the
    /// tracker's configuration.
    pub fn new(camera: &PinholeCamera, config: &TrackerConfig) -> Self {
        let n_levels = config.pyramid_levels as usize;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let levels = (0..n_levels)
            .map(|l| KeyframeLevel {
                points: Vec::with_capacity(config.max_points_per_level(l)),
                camera: camera.pinhole().scaled_to_level(l as u32),
            })
            .collect();
        Self {
            id: 0,
            world_from_keyframe: Pose::identity(),
            requested_at_ns: 0,
            median_depth_m: 0.0,
            gate_level: 0,
            levels,
            scratch: PrepScratch {
                gray: Pyramid::new(w, h, n_levels),
                depth: (0..n_levels)
                    .map(|l| ImageF32::new((w >> l).max(1), (h >> l).max(1), NO_DEPTH))
                    .collect(),
                grad: ImageF32::new(w, h, 0.0),
                depth_min3: ImageF32::new(w, h, 0.0),
                depth_max3: ImageF32::new(w, h, 0.0),
                hist: vec![0; HIST_BINS],
                thresholds: vec![0.0; w.div_ceil(MIN_BLOCK_PX) * h.div_ceil(MIN_BLOCK_PX)],
                depths: Vec::with_capacity(config.max_points_per_level(0)),
                mask: vec![0; w * h],
                any_row: vec![0; w],
            },
        }
    }

    /// The rendered intensities of the finest level (ideal pinhole, gray
    /// levels 0..=255), as the last [`Keyframe::prepare`] left them.
    pub fn gray(&self) -> &ImageF32 {
        self.scratch.gray.level(0)
    }

    /// The rendered metric depth of the finest level (meters; `NO_DEPTH`
    /// where nothing was drawn), as the last [`Keyframe::prepare`] left it.
    pub fn depth_m(&self) -> &ImageF32 {
        &self.scratch.depth[0]
    }

    /// Number of points at level `l`.
    pub fn point_count(&self, l: usize) -> usize {
        self.levels.get(l).map_or(0, |lv| lv.points.len())
    }

    /// The rendered gray pyramid this keyframe was prepared from.
    pub fn gray_pyramid(&self) -> &Pyramid {
        &self.scratch.gray
    }

    /// Fills this keyframe from a rendered `view` at `world_from_keyframe`.
    pub fn prepare(
        &mut self,
        view: &RenderedView,
        world_from_keyframe: Pose,
        id: u64,
        config: &TrackerConfig,
    ) {
        self.id = id;
        self.world_from_keyframe = world_from_keyframe;
        let s = &mut self.scratch;
        s.gray.fill_from_f32(&view.gray);
        s.depth[0].data_mut().copy_from_slice(view.depth_m.data());
        for l in 1..s.depth.len() {
            let (lower, upper) = s.depth.split_at_mut(l);
            downsample_depth(&lower[l - 1], &mut upper[0]);
        }
        for (l, level) in self.levels.iter_mut().enumerate() {
            level.points.clear();
            select_level(
                s.gray.level(l),
                &s.depth[l],
                &level.camera,
                config,
                l,
                &mut s.grad,
                [&mut s.depth_min3, &mut s.depth_max3],
                &mut s.hist,
                &mut s.thresholds,
                [&mut s.mask, &mut s.any_row],
                &mut level.points,
            );
        }
        s.depths.clear();
        s.depths
            .extend(self.levels[0].points.iter().map(|p| p.p_keyframe[2]));
        self.median_depth_m = if s.depths.is_empty() {
            0.0
        } else {
            let mid = s.depths.len() / 2;
            *s.depths.select_nth_unstable_by(mid, f32::total_cmp).1
        };
        self.gate_level = gate_level(
            view.detail_m,
            self.median_depth_m,
            self.levels[0].camera.fx as f32,
        );
    }
}

/// Depth at level l+1: mean of the 2x2 children when all four are valid and
/// continuous (max/min below 1.1), else no depth.
fn downsample_depth(src: &ImageF32, dst: &mut ImageF32) {
    let sw = src.width();
    let s = src.data();
    for y in 0..dst.height() {
        let out = dst.row_mut(y);
        for (x, o) in out.iter_mut().enumerate() {
            let i = 2 * y * sw + 2 * x;
            let d = [s[i], s[i + 1], s[i + sw], s[i + sw + 1]];
            let lo = d.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = d.iter().copied().fold(0.0f32, f32::max);
            *o = if RenderedView::is_hit(lo) && hi <= lo * 1.1 {
                0.25 * (d[0] + d[1] + d[2] + d[3])
            } else {
                NO_DEPTH
            };
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn select_level(
    gray: &ImageF32,
    depth: &ImageF32,
    camera: &PinholeCamera,
    config: &TrackerConfig,
    level: usize,
    grad: &mut ImageF32,
    [min3, max3]: [&mut ImageF32; 2],
    hist: &mut [u32],
    thresholds: &mut [f32],
    [mask, any_row]: [&mut [u8]; 2],
    out: &mut Vec<KeyPoint>,
) {
    let (w, h) = (gray.width(), gray.height());
    if w < 8 || h < 8 {
        return;
    }
    let g = gray.data();
    let d = depth.data();
    // Row-wise 3-pixel depth extremes; the 3x3 test below combines three
    // rows of them (separable; the row loops run on slices cut to one
    // length, so they compile without bounds checks and vectorize). Depths
    // are never NaN, so plain comparisons stand in for f32::min/max.
    let (min3, max3) = (&mut min3.data_mut()[..w * h], &mut max3.data_mut()[..w * h]);
    let lesser = |a: f32, b: f32| if a < b { a } else { b };
    let greater = |a: f32, b: f32| if a > b { a } else { b };
    let n = w - 2;
    for ((row, lo), hi) in d
        .chunks_exact(w)
        .zip(min3.chunks_exact_mut(w))
        .zip(max3.chunks_exact_mut(w))
    {
        let (left, mid, right) = (&row[..n], &row[1..n + 1], &row[2..n + 2]);
        let (lo, hi) = (&mut lo[1..n + 1], &mut hi[1..n + 1]);
        for k in 0..n {
            lo[k] = lesser(lesser(left[k], mid[k]), right[k]);
            hi[k] = greater(greater(left[k], mid[k]), right[k]);
        }
    }
    let gradm = &mut grad.data_mut()[..w * h];
    // Gradient magnitude where the 3x3 depth neighbourhood is valid and
    // continuous; 0 elsewhere (never selected).
    let border = 2;
    gradm.fill(0.0);
    let n = w - 2 * border;
    let (min3, max3): (&[f32], &[f32]) = (min3, max3);
    fn cut(s: &[f32], at: usize, n: usize) -> &[f32] {
        &s[at..at + n]
    }
    for y in border..h - border {
        let i = y * w + border;
        let row = |s, at| cut(s, at, n);
        let (left, right, up, down) = (row(g, i - 1), row(g, i + 1), row(g, i - w), row(g, i + w));
        let (lo_u, lo_c, lo_d) = (row(min3, i - w), row(min3, i), row(min3, i + w));
        let (hi_u, hi_c, hi_d) = (row(max3, i - w), row(max3, i), row(max3, i + w));
        let out = &mut gradm[i..i + n];
        for k in 0..n {
            let lo = lesser(lesser(lo_u[k], lo_c[k]), lo_d[k]);
            let hi = greater(greater(hi_u[k], hi_c[k]), hi_d[k]);
            let gx: f32 = 0.5 * (right[k] - left[k]);
            let gy: f32 = 0.5 * (down[k] - up[k]);
            // Both sides always computed (no branch), so the loop vectorizes.
            let magnitude = (gx * gx + gy * gy).sqrt();
            let valid = RenderedView::is_hit(lo) & (hi <= lo * 1.15);
            out[k] = if valid { magnitude } else { 0.0 };
        }
    }
    let gradm: &[f32] = gradm;
    // Block-adaptive threshold: block median of valid gradients + offset,
    // computed once per block.
    let block = (config.block_size_px as usize >> level).max(MIN_BLOCK_PX);
    let max_points = config.max_points_per_level(level);
    let offset = config.gradient_threshold_gray;
    let blocks_x = w.div_ceil(block);
    let n_blocks = blocks_x * h.div_ceil(block);
    let thresholds = &mut thresholds[..n_blocks];
    for (b, t) in thresholds.iter_mut().enumerate() {
        let (bx, by) = ((b % blocks_x) * block, (b / blocks_x) * block);
        let (bw, bh) = (block.min(w - bx), block.min(h - by));
        *t = block_median(gradm, w, bx, by, bw, bh, hist) + offset;
    }
    let thresholds: &[f32] = thresholds;
    // Which pixels pass their block's threshold, once: the bisection below
    // counts cells over these bytes, five times or so, instead of finding
    // each cell's strongest gradient each time.
    let mask = &mut mask[..w * h];
    for (y, row) in mask.chunks_exact_mut(w).enumerate() {
        let grow = &gradm[y * w..(y + 1) * w];
        let trow = &thresholds[(y / block) * blocks_x..(y / block + 1) * blocks_x];
        for ((m, gv), &t) in row.chunks_mut(block).zip(grow.chunks(block)).zip(trow) {
            for (m, &gv) in m.iter_mut().zip(gv) {
                *m = u8::from(gv > t);
            }
        }
    }
    // The smallest cell (2..=16 px) whose selection fits the budget: the
    // count falls as the cell grows, so bisect.
    let mut fits = |cell: usize| count_cells(mask, w, h, block, cell, any_row) <= max_points;
    let cell = if fits(2) {
        2
    } else {
        let (mut bad, mut good) = (2usize, 16usize);
        while good - bad > 1 {
            let mid = (bad + good) / 2;
            if fits(mid) {
                good = mid;
            } else {
                bad = mid;
            }
        }
        good
    };
    select_cells(gradm, w, h, block, cell, thresholds, Some(out));
    out.truncate(max_points);
    // Back-project and precompute Jacobians.
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    for kp in out.iter_mut() {
        // `select_cells` stores the pixel index in p_keyframe[0]'s bits.
        let i = kp.p_keyframe[0].to_bits() as usize;
        let (x, y) = (i % w, i / w);
        let gx = 0.5 * (g[i + 1] - g[i - 1]);
        let gy = 0.5 * (g[i + w] - g[i - w]);
        *kp = KeyPoint::from_pixel(x as f32, y as f32, d[i], g[i], gx, gy, [fx, fy, cx, cy]);
    }
}

/// How many `cell x cell` cells (cut at block edges, as [`select_cells`]
/// cuts them) hold a pixel of `mask` (`w x h`, one byte per pixel, 1 where
/// it passes its block's threshold): the count [`select_cells`] gives,
/// without finding each cell's strongest pixel. `any_row` (`w` bytes) is
/// scratch: the rows of a row of cells OR-ed together.
fn count_cells(
    mask: &[u8],
    w: usize,
    h: usize,
    block: usize,
    cell: usize,
    any_row: &mut [u8],
) -> usize {
    let any_row = &mut any_row[..w];
    let mut count = 0;
    let mut by = 0;
    while by < h {
        let y_end = (by + block).min(h);
        let mut cy = by;
        while cy < y_end {
            let cy_end = (cy + cell).min(y_end);
            any_row.copy_from_slice(&mask[cy * w..(cy + 1) * w]);
            for y in cy + 1..cy_end {
                for (a, &m) in any_row.iter_mut().zip(&mask[y * w..(y + 1) * w]) {
                    *a |= m;
                }
            }
            for block_row in any_row.chunks(block) {
                for c in block_row.chunks(cell) {
                    count += usize::from(c.iter().any(|&m| m != 0));
                }
            }
            cy = cy_end;
        }
        by = y_end;
    }
    count
}

/// Picks the strongest pixel above its block's threshold (`thresholds`,
/// row-major by block) in each `cell x cell` cell; returns the count, and
/// pushes them (up to `out`'s capacity) when `out` is given.
fn select_cells(
    gradm: &[f32],
    w: usize,
    h: usize,
    block: usize,
    cell: usize,
    thresholds: &[f32],
    mut out: Option<&mut Vec<KeyPoint>>,
) -> usize {
    let blocks_x = w.div_ceil(block);
    let mut count = 0;
    let mut by = 0;
    while by < h {
        let bh = block.min(h - by);
        let mut bx = 0;
        while bx < w {
            let bw = block.min(w - bx);
            let thresh = thresholds[(by / block) * blocks_x + bx / block];
            let mut cy = by;
            while cy < by + bh {
                let mut cx = bx;
                while cx < bx + bw {
                    let mut best_i = u32::MAX;
                    let mut best_g = thresh;
                    for y in cy..(cy + cell).min(by + bh) {
                        for x in cx..(cx + cell).min(bx + bw) {
                            let gv = gradm[y * w + x];
                            if gv > best_g {
                                best_g = gv;
                                best_i = (y * w + x) as u32;
                            }
                        }
                    }
                    if best_i != u32::MAX {
                        count += 1;
                        if let Some(o) = out.as_deref_mut() {
                            if o.len() < o.capacity() {
                                o.push(KeyPoint {
                                    p_keyframe: [f32::from_bits(best_i), 0.0, 0.0],
                                    ..KeyPoint::default()
                                });
                            }
                        }
                    }
                    cx += cell;
                }
                cy += cell;
            }
            bx += block;
        }
        by += block;
    }
    count
}

/// Median of the non-zero gradient magnitudes in a block, by histogram.
fn block_median(
    gradm: &[f32],
    w: usize,
    bx: usize,
    by: usize,
    bw: usize,
    bh: usize,
    hist: &mut [u32],
) -> f32 {
    hist.fill(0);
    let mut n = 0u32;
    for y in by..by + bh {
        for &gv in &gradm[y * w + bx..y * w + bx + bw] {
            if gv > 0.0 {
                hist[(gv as usize).min(HIST_BINS - 1)] += 1;
                n += 1;
            }
        }
    }
    if n == 0 {
        return f32::INFINITY;
    }
    let mut acc = 0;
    for (b, &c) in hist.iter().enumerate() {
        acc += c;
        if acc * 2 >= n {
            return b as f32 + 0.5;
        }
    }
    HIST_BINS as f32
}

#[cfg(test)]
mod gate_level_tests {
    use super::*;

    #[test]
    fn the_gates_start_where_the_pixels_are_as_coarse_as_the_map() {
        // 420 px focal length, 2.5 m away: 6 mm pixels at level 0.
        assert_eq!(gate_level(0.0078, 2.5, 420.0), 0, "a textured map");
        assert_eq!(gate_level(0.0108, 2.5, 420.0), 0, "scanned at 1 cm");
        assert_eq!(gate_level(0.0228, 2.5, 420.0), 1, "scanned at 2 cm");
        assert_eq!(gate_level(0.0228, 5.0, 420.0), 0, "2 cm, from 5 m");
        assert_eq!(gate_level(0.1, 1.0, 420.0), MAX_GATE_LEVEL, "capped");
    }

    #[test]
    fn no_detail_or_no_depth_reads_every_level() {
        assert_eq!(gate_level(0.0, 2.5, 420.0), 0);
        assert_eq!(gate_level(0.05, 0.0, 420.0), 0);
        assert_eq!(gate_level(f32::NAN, 2.5, 420.0), 0);
        assert_eq!(gate_level(0.05, 2.5, f32::NAN), 0);
    }
}

#[cfg(test)]
mod selection_tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The bisection counts cells over the threshold mask; the count must
    /// be what the selection itself finds, for every cell size, with
    /// blocks cut at the image's edges.
    #[test]
    fn cells_counted_over_the_mask_are_the_cells_selected() {
        let mut rng = SplitMix64::new(3);
        for (w, h, block) in [(64usize, 48usize, 16usize), (71, 53, 16), (40, 37, 8)] {
            let gradm: Vec<f32> = (0..w * h)
                .map(|_| {
                    if rng.below(10) < 8 {
                        0.0
                    } else {
                        rng.below(40) as f32
                    }
                })
                .collect();
            let (blocks_x, block_rows) = (w.div_ceil(block), h.div_ceil(block));
            let thresholds: Vec<f32> = (0..blocks_x * block_rows)
                .map(|_| 10.0 + rng.below(25) as f32)
                .collect();
            let mask: Vec<u8> = (0..w * h)
                .map(|i| {
                    let t = thresholds[(i / w / block) * blocks_x + (i % w) / block];
                    u8::from(gradm[i] > t)
                })
                .collect();
            let mut any_row = vec![0u8; w];
            for cell in 2..=16 {
                let selected = select_cells(&gradm, w, h, block, cell, &thresholds, None);
                let counted = count_cells(&mask, w, h, block, cell, &mut any_row);
                assert_eq!(counted, selected, "{w}x{h}, block {block}, cell {cell}");
                assert!(selected > 0);
            }
        }
    }
}
