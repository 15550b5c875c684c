//! Image pyramids for the tracker, allocated once and refilled per frame.
//!
//! Level 0 is full resolution. Each level halves the size with the separable
//! binomial kernel `[1 3 3 1] / 8` centered between two pixels, which matches
//! the pixel-center convention of [`PinholeCamera::scaled_to_level`]: pixel
//! `x` of level `l + 1` is centered at `2x + 0.5` of level `l`.
//!
//! [`PinholeCamera::scaled_to_level`]: crate::geometry::PinholeCamera::scaled_to_level

use crate::imgproc::ImageF32;

/// A Gaussian pyramid of float images with preallocated levels.
#[derive(Debug, Clone)]
pub struct Pyramid {
    levels: Vec<ImageF32>,
    /// Scratch for the horizontal pass, sized for level 1's width x level 0's height.
    scratch: Vec<f32>,
}

impl Pyramid {
    /// Allocates `levels` levels for a `width x height` base image.
    pub fn new(width: usize, height: usize, levels: usize) -> Self {
        let levels = levels.max(1);
        let levels: Vec<ImageF32> = (0..levels)
            .map(|l| ImageF32::new((width >> l).max(1), (height >> l).max(1), 0.0))
            .collect();
        Self {
            levels,
            scratch: vec![0.0; (width / 2).max(1) * height.max(1)],
        }
    }

    /// Number of levels.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Always false: a pyramid has at least one level.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `l` (0 = full resolution).
    pub fn level(&self, l: usize) -> &ImageF32 {
        &self.levels[l]
    }

    /// Width and height of level 0.
    pub fn size(&self) -> (usize, usize) {
        (self.levels[0].width(), self.levels[0].height())
    }

    /// Fills level 0 from an 8-bit image with row stride `stride` (bytes)
    /// and rebuilds the other levels. The caller checks the sizes.
    pub fn fill_from_u8(&mut self, pixels: &[u8], stride: usize) {
        let base = &mut self.levels[0];
        let w = base.width();
        for y in 0..base.height() {
            let src = &pixels[y * stride..y * stride + w];
            for (d, &s) in base.row_mut(y).iter_mut().zip(src) {
                *d = s as f32;
            }
        }
        self.rebuild_from_base();
    }

    /// Copies level 0 from a float image of the same size and rebuilds the rest.
    pub fn fill_from_f32(&mut self, image: &ImageF32) {
        self.levels[0].data_mut().copy_from_slice(image.data());
        self.rebuild_from_base();
    }

    /// Recomputes levels 1.. from level 0.
    pub fn rebuild_from_base(&mut self) {
        for l in 1..self.levels.len() {
            let (lower, upper) = self.levels.split_at_mut(l);
            downsample(&lower[l - 1], &mut upper[0], &mut self.scratch);
        }
    }
}

/// Halves `src` into `dst` with the `[1 3 3 1] / 8` kernel, clamping at borders.
fn downsample(src: &ImageF32, dst: &mut ImageF32, scratch: &mut [f32]) {
    let (sw, sh) = (src.width(), src.height());
    let (dw, dh) = (dst.width(), dst.height());
    // Horizontal pass: sh rows of dw samples.
    let tmp = &mut scratch[..dw * sh];
    // Output x reads input 2x-1..=2x+2; x in 1..interior needs no clamping.
    let interior = if sw >= 3 {
        ((sw - 3) / 2 + 1).min(dw)
    } else {
        0
    };
    let clamped = |row: &[f32], x: usize| {
        let c0 = 2 * x;
        let a = row[c0.saturating_sub(1)];
        let b = row[c0.min(sw - 1)];
        let c = row[(c0 + 1).min(sw - 1)];
        let d = row[(c0 + 2).min(sw - 1)];
        (a + 3.0 * (b + c) + d) * 0.125
    };
    for y in 0..sh {
        let row = src.row(y);
        let out = &mut tmp[y * dw..(y + 1) * dw];
        if interior > 1 {
            for (x, o) in out[1..interior].iter_mut().enumerate() {
                let w = &row[2 * x + 1..2 * x + 5];
                *o = (w[0] + 3.0 * (w[1] + w[2]) + w[3]) * 0.125;
            }
        }
        out[0] = clamped(row, 0);
        for x in interior.max(1)..dw {
            out[x] = clamped(row, x);
        }
    }
    // Vertical pass.
    for y in 0..dh {
        let r0 = 2 * y;
        let ra = r0.saturating_sub(1) * dw;
        let rb = r0 * dw;
        let rc = (r0 + 1).min(sh - 1) * dw;
        let rd = (r0 + 2).min(sh - 1) * dw;
        let out = dst.row_mut(y);
        for (x, o) in out.iter_mut().enumerate() {
            *o = (tmp[ra + x] + 3.0 * (tmp[rb + x] + tmp[rc + x]) + tmp[rd + x]) * 0.125;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_image_stays_constant() {
        let mut p = Pyramid::new(64, 48, 4);
        let img = vec![77u8; 64 * 48];
        p.fill_from_u8(&img, 64);
        for l in 0..4 {
            assert!(p.level(l).data().iter().all(|&v| (v - 77.0).abs() < 1e-4));
        }
        assert_eq!(p.level(3).width(), 8);
        assert_eq!(p.level(3).height(), 6);
    }

    #[test]
    fn linear_ramp_keeps_pixel_centers() {
        // I(x) = x at level 0 -> level 1 pixel x is centered at 2x + 0.5.
        let (w, h) = (64usize, 8usize);
        let img: Vec<f32> = (0..w * h).map(|i| (i % w) as f32).collect();
        let mut p = Pyramid::new(w, h, 2);
        p.fill_from_f32(&ImageF32::from_vec(w, h, img).expect("size"));
        let l1 = p.level(1);
        for x in 1..l1.width() - 1 {
            let v = l1.get(x, 3).expect("inside");
            assert!((v - (2.0 * x as f32 + 0.5)).abs() < 1e-4, "x {x}: {v}");
        }
    }

    #[test]
    fn stride_is_respected() {
        let (w, h, stride) = (5usize, 3usize, 8usize);
        let mut px = vec![255u8; stride * h];
        for y in 0..h {
            for x in 0..w {
                px[y * stride + x] = (y * 10 + x) as u8;
            }
        }
        let mut p = Pyramid::new(w, h, 1);
        p.fill_from_u8(&px, stride);
        assert_eq!(p.level(0).get(4, 2), Some(24.0));
    }
}
