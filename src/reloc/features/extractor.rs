//! The feature extractor: FAST corners ([`super::fast`]) on an image
//! pyramid ([`super::pyramid`]), the best of them spread over the image and
//! split between the levels by area, each described by BRIEF
//! ([`super::brief`]).
//!
//! Takes an 8-bit gray image (`&[u8]`, width, height, row stride); gives out
//! [`Keypoint`]s in level-0 pixel coordinates (pixel centers at integers).
//! [`FeatureExtractor`] owns the pyramid, the score map, the candidate lists
//! and the comparison pattern: after [`FeatureExtractor::new`],
//! [`FeatureExtractor::extract`] allocates nothing.

use super::brief::{blur, describe, draw_pattern, EDGE_PX};
use super::fast::{detect, select, Candidate, CIRCLE};
use super::pyramid::{downscale, shrink, tap, Level};
use crate::reloc::descriptor::Descriptor;

/// Most pyramid levels; [`FeatureParams::levels`] is clamped to this.
pub const MAX_LEVELS: usize = 8;

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

    /// The keypoints of the last [`Self::extract`].
    pub fn keypoints(&self) -> &[Keypoint] {
        &self.keypoints
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reloc::features::test_images::render;

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
}
