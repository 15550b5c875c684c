//! FAST-9 corner detection (Rosten) on one pyramid level, 3x3 non-maximum
//! suppression, and the selection of the best corners spread over a grid.
//!
//! Takes a `Level` (its image, size and the circle's offsets for its row
//! pitch) and a threshold; gives `Candidate` corners in level pixels,
//! then marks the `budget` picked ones. Scores are computed branch-free over
//! 32 pixels at a time (AVX2 where the CPU has it). Writes only into the
//! caller's buffers.

use super::brief::EDGE_PX;
use super::pyramid::Level;

/// The Bresenham circle of radius 3 (dx, dy), clockwise from the top.
#[rustfmt::skip]
pub(super) const CIRCLE: [(isize, isize); 16] = [
    (0, -3), (1, -3), (2, -2), (3, -1), (3, 0), (3, 1), (2, 2), (1, 3),
    (0, 3), (-1, 3), (-2, 2), (-3, 1), (-3, 0), (-3, -1), (-2, -2), (-1, -3),
];

/// A corner after non-maximum suppression, in level pixels.
#[derive(Debug, Clone, Copy)]
pub(super) struct Candidate {
    pub(super) x: u32,
    pub(super) y: u32,
    pub(super) score: u16,
    pub(super) picked: bool,
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
pub(super) fn detect(level: &Level, threshold: u8, scores: &mut [u16], out: &mut Vec<Candidate>) {
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
pub(super) fn select(
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

#[cfg(test)]
mod tests {
    use crate::reloc::features::{FeatureExtractor, FeatureParams, Keypoint};
    use crate::rng::SplitMix64;

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
}
