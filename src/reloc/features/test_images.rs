//! Test images for the feature tests: smooth value noise rendered at any
//! scale and offset, and a median.

use crate::rng::SplitMix64;

/// Value noise (octaves of 16, 8 and 4 px, smoothstep), contrast
/// stretched with saturation, at `(x, y)` pixels.
pub(super) fn noise(x: f32, y: f32) -> f32 {
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
pub(crate) fn render(w: usize, h: usize, scale: f32, dx: f32, dy: f32) -> Vec<u8> {
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

pub(super) fn median(mut v: Vec<u32>) -> u32 {
    v.sort_unstable();
    v.get(v.len() / 2).copied().unwrap_or(u32::MAX)
}
