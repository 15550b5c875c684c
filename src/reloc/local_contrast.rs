//! Local contrast normalization of the images a relocalization aligns: each
//! pixel as its distance from the mean of its neighbourhood, in units of
//! the neighbourhood's standard deviation.
//!
//! Owns [`LocalContrast`]: its integral images, sized once for one image
//! size, and the normalized copy of a camera frame. Takes an 8-bit frame
//! ([`LocalContrast::frame`]) or a rendered view, normalized in place over
//! the pixels that hit the map ([`LocalContrast::view`]); gives
//! `128 + 32 (I - mean) / max(std, floor)`, clamped to `1..=255`.
//!
//! *Why.* A scanned map carries the light of the scan baked into its
//! colors, and the flight sees another light: each surface's gain differs
//! between the two images, so the aligner's one affine gain and bias cannot
//! explain them, and a candidate a few decimeters off settles 7-30 cm from
//! the truth on dark, flat walls. A gain that is constant over a window of
//! the radius cancels in the normalized images, so only the texture and
//! the edges inside each window are left to align.
//! `star bench reloc` takes it with `STAR_BENCH_NORMALIZE_PX`
//! (docs/building-scale.md, "Aligning on local contrast"). After
//! [`LocalContrast::new`] nothing here allocates.

use crate::render::RenderedView;

/// Gray level of a pixel at its neighbourhood's mean.
const MID_GRAY: f64 = 128.0;
/// Gray levels per standard deviation.
const GRAY_PER_STD: f64 = 32.0;

/// Normalizes images of one size; see the module docs.
#[derive(Debug, Clone)]
pub struct LocalContrast {
    width: usize,
    height: usize,
    radius_px: usize,
    floor_gray: f64,
    /// Integral images, `(width + 1) x (height + 1)`: of the valid gray, of
    /// its square, and of the valid pixels.
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    count: Vec<f64>,
    /// The last normalized frame.
    frame: Vec<u8>,
}

impl LocalContrast {
    /// Buffers for `width x height` images, windows of `(2 radius_px + 1)^2`
    /// pixels (at least 3 x 3), and a standard deviation counted as at
    /// least `floor_gray` (at least 0.1): a flat, dark wall's noise is not
    /// blown up into texture.
    pub fn new(width: usize, height: usize, radius_px: usize, floor_gray: f32) -> Self {
        let n = (width + 1) * (height + 1);
        Self {
            width,
            height,
            radius_px: radius_px.max(1),
            floor_gray: if floor_gray.is_finite() {
                f64::from(floor_gray).max(0.1)
            } else {
                0.1
            },
            sum: vec![0.0; n],
            sum_sq: vec![0.0; n],
            count: vec![0.0; n],
            frame: vec![0; width * height],
        }
    }

    /// The normalized copy of `frame` (`width x height`, row-major, tightly
    /// packed); `None` when its size is not the one of [`Self::new`].
    pub fn frame(&mut self, frame: &[u8]) -> Option<&[u8]> {
        if frame.len() != self.width * self.height {
            return None;
        }
        self.integrate(|i| Some(f64::from(frame[i])));
        for i in 0..frame.len() {
            let v = self.normalized(i, f64::from(frame[i]));
            self.frame[i] = v.round() as u8;
        }
        Some(&self.frame)
    }

    /// Normalizes `view`'s gray in place over its hit pixels, each against
    /// the hit pixels of its window only (the edge of the map is not a
    /// dark neighbour). Pixels that miss keep their gray. False (and the
    /// view untouched) when its size is not the one of [`Self::new`].
    pub fn view(&mut self, view: &mut RenderedView) -> bool {
        let n = self.width * self.height;
        if view.gray.width() != self.width
            || view.gray.height() != self.height
            || view.depth_m.data().len() != n
        {
            return false;
        }
        {
            let (gray, depth) = (view.gray.data(), view.depth_m.data());
            self.integrate(|i| RenderedView::is_hit(depth[i]).then(|| f64::from(gray[i])));
        }
        let (gray, depth) = (view.gray.data_mut(), view.depth_m.data());
        for i in 0..n {
            if RenderedView::is_hit(depth[i]) {
                gray[i] = self.normalized(i, f64::from(gray[i])) as f32;
            }
        }
        true
    }

    /// Fills the integral images from `at(i)`: the gray of pixel `i`, or
    /// `None` where it is not counted.
    fn integrate(&mut self, at: impl Fn(usize) -> Option<f64>) {
        let (w, h) = (self.width, self.height);
        let stride = w + 1;
        for y in 0..h {
            let (mut row, mut row_sq, mut row_n) = (0.0, 0.0, 0.0);
            for x in 0..w {
                if let Some(g) = at(y * w + x) {
                    row += g;
                    row_sq += g * g;
                    row_n += 1.0;
                }
                let (above, here) = (y * stride + x + 1, (y + 1) * stride + x + 1);
                self.sum[here] = self.sum[above] + row;
                self.sum_sq[here] = self.sum_sq[above] + row_sq;
                self.count[here] = self.count[above] + row_n;
            }
        }
    }

    /// The normalized value of pixel `i` of gray `g`.
    fn normalized(&self, i: usize, g: f64) -> f64 {
        let (w, h, r) = (self.width, self.height, self.radius_px);
        let (x, y) = (i % w, i / w);
        let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        let stride = w + 1;
        let window = |s: &[f64]| {
            s[y1 * stride + x1] - s[y0 * stride + x1] - s[y1 * stride + x0] + s[y0 * stride + x0]
        };
        let n = window(&self.count);
        if n < 1.0 {
            return MID_GRAY;
        }
        let mean = window(&self.sum) / n;
        let var = (window(&self.sum_sq) / n - mean * mean).max(0.0);
        (MID_GRAY + GRAY_PER_STD * (g - mean) / var.sqrt().max(self.floor_gray)).clamp(1.0, 255.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texture(w: usize, h: usize) -> Vec<f64> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                60.0 + 30.0 * (0.7 * x).sin() * (0.45 * y).cos() + 0.5 * x
            })
            .collect()
    }

    #[test]
    fn a_gain_and_an_offset_cancel() {
        let (w, h) = (48, 40);
        let t = texture(w, h);
        let a: Vec<u8> = t.iter().map(|&v| v.round() as u8).collect();
        // Twice as bright plus 10: the same image after normalization,
        // within the rounding of the 8-bit input and output.
        let b: Vec<u8> = t.iter().map(|&v| (2.0 * v + 10.0).round() as u8).collect();
        let mut lc = LocalContrast::new(w, h, 5, 2.0);
        let na = lc.frame(&a).unwrap().to_vec();
        let nb = lc.frame(&b).unwrap().to_vec();
        let worst = na
            .iter()
            .zip(&nb)
            .map(|(p, q)| (i32::from(*p) - i32::from(*q)).abs())
            .max()
            .unwrap();
        assert!(worst <= 3, "largest difference {worst} gray levels");
        // And the output is not flat: the texture is still there.
        let (lo, hi) = (na.iter().min().unwrap(), na.iter().max().unwrap());
        assert!(hi - lo > 100, "range {lo}..{hi}");
    }

    #[test]
    fn the_floor_keeps_a_flat_wall_flat() {
        let (w, h) = (32, 32);
        // +-1 gray of noise on a flat wall: under a floor of 8 it moves the
        // output by 4 gray levels at most, not by whole standard deviations.
        let wall: Vec<u8> = (0..w * h).map(|i| 40 + (i % 3) as u8).collect();
        let mut lc = LocalContrast::new(w, h, 4, 8.0);
        let out = lc.frame(&wall).unwrap();
        assert!(out.iter().all(|&v| (124..=132).contains(&v)), "{out:?}");
    }

    #[test]
    fn a_view_is_normalized_over_its_hits_only() {
        let (w, h) = (40, 30);
        let mut view = RenderedView::new(w, h);
        let t = texture(w, h);
        for (i, (g, d)) in view
            .gray
            .data_mut()
            .iter_mut()
            .zip(view.depth_m.data_mut())
            .enumerate()
        {
            // The left half hits a flat gray wall; the right half misses.
            if i % w < w / 2 {
                *g = 90.0;
                *d = 2.0;
            } else {
                *g = t[i] as f32;
            }
        }
        let mut lc = LocalContrast::new(w, h, 6, 1.0);
        assert!(lc.view(&mut view));
        for (i, (&g, &d)) in view.gray.data().iter().zip(view.depth_m.data()).enumerate() {
            if RenderedView::is_hit(d) {
                // The missing half does not pull the wall's mean down.
                assert_eq!(g, 128.0, "pixel {i}");
            } else {
                assert_eq!(g, t[i] as f32, "pixel {i} missed and must keep its gray");
            }
        }
    }

    #[test]
    fn the_wrong_size_is_refused() {
        let mut lc = LocalContrast::new(8, 8, 2, 1.0);
        assert!(lc.frame(&[0u8; 63]).is_none());
        let mut view = RenderedView::new(8, 7);
        assert!(!lc.view(&mut view));
    }
}
