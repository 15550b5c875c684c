//! The 256-bit upright BRIEF-style descriptor: the comparison pattern, the
//! 5x5 box blur the comparisons are made on, and the description of one
//! keypoint.
//!
//! Takes a `Level` (its image) and a corner's position on it; gives its
//! [`Descriptor`] (bit i set when the first pixel of pair i is darker than
//! the second, on the blurred level). The pattern is drawn once from
//! [`PATTERN_SEED`]: landmark databases store descriptors, so it must not
//! change. Upright: no orientation is estimated (the vehicle's roll stays
//! small, and rotation invariance would cost distinctiveness).

use super::pyramid::Level;
use crate::reloc::descriptor::Descriptor;
use crate::rng::SplitMix64;

/// Side of the square patch the comparison pairs are drawn in, pixels of
/// the keypoint's level.
pub const PATCH_SIZE: usize = 31;
pub(super) const PATCH_HALF: usize = PATCH_SIZE / 2;
/// Radius of the box blur (5x5) the comparisons are made on.
pub(super) const BLUR_RADIUS: usize = 2;
/// Pixels skipped at each level's border: the patch and its blur fit inside.
pub const EDGE_PX: usize = PATCH_HALF + BLUR_RADIUS;
/// Seed of the comparison pattern. Landmark databases store descriptors:
/// changing it (or the pattern's drawing) invalidates them.
pub const PATTERN_SEED: u64 = 0x5354_4152_4645_4154;

/// The 256 comparison pairs `[ax, ay, bx, by]`: offsets i.i.d. Gaussian of
/// sigma `PATCH_SIZE / 5`, redrawn outside the patch (BRIEF's G II).
pub(super) fn draw_pattern() -> Vec<[isize; 4]> {
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

/// 5x5 box sums of the level's interior (2 pixels in from each border; the
/// patches never read closer), into `level.smooth`.
pub(super) fn blur(level: &mut Level, row_sums: &mut [u16]) {
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
pub(super) fn describe(smooth: &[u16], center: usize, pairs: &[(isize, isize)]) -> Descriptor {
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

#[cfg(test)]
mod tests {
    use crate::reloc::features::test_images::{median, render};
    use crate::reloc::features::{FeatureExtractor, FeatureParams, Keypoint};

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
}
