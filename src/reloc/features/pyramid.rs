//! The image pyramid of the feature extractor: one `Level` per scale, each
//! the previous one shrunk by the scale factor (bilinear, 8-bit fixed-point
//! weights).
//!
//! Takes the level-0 image (copied in by [`super::FeatureExtractor`]); gives
//! every level's image at its size, in buffers sized once for the largest
//! image. Allocates nothing after the levels are built.

/// One pyramid level: its image, its smoothed image (5x5 box sums,
/// [`super::brief`]) and the FAST circle's and BRIEF pattern's offsets for
/// its row pitch.
#[derive(Debug, Clone)]
pub(super) struct Level {
    /// Row pitch of `image` and `smooth` (the level's width at capacity).
    pub(super) stride: usize,
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) image: Vec<u8>,
    pub(super) smooth: Vec<u16>,
    /// Horizontal taps into the previous level ([`tap`]).
    pub(super) taps: Vec<(usize, u32)>,
    pub(super) circle: [isize; 16],
    pub(super) pairs: Vec<(isize, isize)>,
}

/// Size of the next level: the previous one shrunk by `scale`.
pub(super) fn shrink(n: usize, scale: f32) -> usize {
    (n as f32 / scale) as usize
}

/// Bilinear resize of `src` by `1 / scale` into `dst` (sets `dst`'s size).
/// Level pixel `x` samples the previous level at `(x + 0.5) * scale - 0.5`.
pub(super) fn downscale(src: &Level, dst: &mut Level, scale: f32) {
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
pub(super) fn tap(i: usize, scale: f32) -> (usize, u32) {
    let p = ((i as f32 + 0.5) * scale - 0.5).max(0.0);
    let i0 = p as usize;
    (i0, ((p - i0 as f32).min(1.0) * 256.0) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reloc::features::test_images::{median, render};
    use crate::reloc::features::{best_two, FeatureExtractor, FeatureParams, Keypoint};

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
}
