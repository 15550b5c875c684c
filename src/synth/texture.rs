//! Procedural gray textures for the synthetic scene, and the seeded PRNG
//! behind every random choice in it.
//!
//! Takes a surface kind, its size in meters, a resolution and a seed; gives
//! out a [`GrayTexture`] (0..=255). Everything is built from integer hashing
//! and `+ - * / sqrt` only (no transcendental functions), so the same seed
//! gives bit-identical textures on every platform.
//!
//! Building blocks here (with [`crate::rng`]'s [`SplitMix64`]): lattice value noise and fBm
//! ([`fbm`]), and a [`Canvas`] with anti-aliased rectangles, frames and
//! disks (exact box-filter coverage). The per-surface designs (planks,
//! tiles, painted walls with posters and doors, ceiling panels, furniture
//! fronts, clothing-like occluders) are in `texture/paint.rs`.

mod objects;
mod paint;
mod wall;

use crate::map::GrayTexture;
pub use crate::rng::{mix64, SplitMix64};

pub use paint::paint_surface;

/// Largest texture side in texels (a common GPU limit).
pub const MAX_TEXTURE_SIDE: u32 = 8192;
/// Largest texture in texels (64 MB as `f32`).
pub const MAX_TEXELS: usize = 16 << 20;

/// Kinds of surface, each with its own texture design.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SurfaceKind {
    /// Floor: wooden planks or tiles with grout, chosen by seed.
    Floor,
    /// Wall: noisy paint, framed posters and notes, skirting, a door.
    Wall,
    /// Ceiling: suspended panels with frames, lights and vents.
    Ceiling,
    /// Furniture atlas: wood and panel fronts with handles and labels.
    Furniture,
    /// Occluder atlas (objects not in the map): stripes and blotches.
    Occluder,
}

/// Hash of a lattice point to `[-1, 1]`.
#[inline]
fn lattice(seed: u64, x: i64, y: i64) -> f64 {
    let h = mix64(
        seed ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F),
    );
    (h >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0
}

/// Value noise in `[-1, 1]` with unit lattice spacing, C2-smooth (quintic
/// fade), not periodic.
pub fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (ix, iy) = (fx as i64, fy as i64);
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (tx, ty) = (fade(x - fx), fade(y - fy));
    let a = lattice(seed, ix, iy);
    let b = lattice(seed, ix + 1, iy);
    let c = lattice(seed, ix, iy + 1);
    let d = lattice(seed, ix + 1, iy + 1);
    let top = a + (b - a) * tx;
    let bottom = c + (d - c) * tx;
    top + (bottom - top) * ty
}

/// Fractal sum of `octaves` value-noise layers at `(x, y)` meters: the first
/// has wavelength `wavelength_m`, each next one 0.47x the wavelength
/// (not 0.5, to avoid lattice alignment) and `gain` times the amplitude.
/// Roughly in `[-1, 1]`.
pub fn fbm(seed: u64, x: f64, y: f64, wavelength_m: f64, octaves: u32, gain: f64) -> f64 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut amplitude = 1.0;
    let mut frequency = 1.0 / wavelength_m;
    for octave in 0..octaves {
        let s = mix64(seed.wrapping_add(u64::from(octave)));
        // Offsets keep octaves' lattices from sharing the origin.
        let off = 17.31 * f64::from(octave);
        sum += amplitude * value_noise(s, x * frequency + off, y * frequency - off);
        norm += amplitude;
        amplitude *= gain;
        frequency *= 1.0 / 0.47;
    }
    sum / norm
}

/// An axis-aligned rectangle in texture meters (`x` right, `y` down).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    /// Left edge.
    pub x0: f64,
    /// Top edge.
    pub y0: f64,
    /// Right edge.
    pub x1: f64,
    /// Bottom edge.
    pub y1: f64,
}

impl Rect {
    /// From the top-left corner and a size.
    pub fn new(x: f64, y: f64, w: f64, h: f64) -> Self {
        Self {
            x0: x,
            y0: y,
            x1: x + w,
            y1: y + h,
        }
    }

    /// Width.
    pub fn w(&self) -> f64 {
        self.x1 - self.x0
    }

    /// Height.
    pub fn h(&self) -> f64 {
        self.y1 - self.y0
    }

    /// Shrunk by `d` on every side (grown when negative).
    pub fn inset(&self, d: f64) -> Self {
        Self {
            x0: self.x0 + d,
            y0: self.y0 + d,
            x1: self.x1 - d,
            y1: self.y1 - d,
        }
    }

    /// True when the two rectangles, each grown by `gap`, overlap.
    pub fn overlaps(&self, other: &Rect, gap: f64) -> bool {
        self.x0 - gap < other.x1
            && other.x0 - gap < self.x1
            && self.y0 - gap < other.y1
            && other.y0 - gap < self.y1
    }
}

/// A gray texture being painted, addressed in meters.
#[derive(Debug, Clone)]
pub struct Canvas {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// Texels per meter.
    pub px_per_m: f64,
    /// Intensities, row-major.
    pub texels: Vec<f32>,
}

impl Canvas {
    /// A canvas covering `width_m x height_m` at about `px_per_m` (lowered
    /// to stay within [`MAX_TEXELS`]; at least 8 texels a side, at most
    /// [`MAX_TEXTURE_SIDE`]; the resolution is then adjusted to fit exactly).
    pub fn new(width_m: f64, height_m: f64, px_per_m: f64) -> Self {
        // Keep one texture within the texel budget.
        let wanted = width_m * height_m * px_per_m * px_per_m;
        let px_per_m = if wanted > MAX_TEXELS as f64 {
            px_per_m * (MAX_TEXELS as f64 / wanted).sqrt()
        } else {
            px_per_m
        };
        let side = |m: f64| ((m * px_per_m).round() as u32).clamp(8, MAX_TEXTURE_SIDE) as usize;
        let (width, height) = (side(width_m), side(height_m));
        let px_per_m = (width as f64 / width_m.max(1e-6)).min(height as f64 / height_m.max(1e-6));
        Self {
            width,
            height,
            px_per_m,
            texels: vec![0.0; width * height],
        }
    }

    /// Size in meters.
    pub fn size_m(&self) -> (f64, f64) {
        (
            self.width as f64 / self.px_per_m,
            self.height as f64 / self.px_per_m,
        )
    }

    /// Sets every texel to `f(x_m, y_m)` at its center.
    pub fn fill_with(&mut self, f: impl Fn(f64, f64) -> f64) {
        let s = 1.0 / self.px_per_m;
        for (row, line) in self.texels.chunks_exact_mut(self.width).enumerate() {
            let y = (row as f64 + 0.5) * s;
            for (col, t) in line.iter_mut().enumerate() {
                *t = f((col as f64 + 0.5) * s, y) as f32;
            }
        }
    }

    /// Blends `f(x_m, y_m, old)` into the texels under `rect`, weighted by
    /// each texel's exact coverage (anti-aliased edges).
    pub fn paint_rect(&mut self, rect: Rect, f: impl Fn(f64, f64, f64) -> f64) {
        let k = self.px_per_m;
        let (x0, x1, y0, y1) = (rect.x0 * k, rect.x1 * k, rect.y0 * k, rect.y1 * k);
        if !(x1 > x0 && y1 > y0) {
            return;
        }
        let cols = (x0.floor().max(0.0) as usize)..(x1.ceil().min(self.width as f64) as usize);
        let rows = (y0.floor().max(0.0) as usize)..(y1.ceil().min(self.height as f64) as usize);
        let cover = |c: f64, lo: f64, hi: f64| ((c + 1.0).min(hi) - c.max(lo)).clamp(0.0, 1.0);
        for row in rows {
            let cy = cover(row as f64, y0, y1);
            let y = (row as f64 + 0.5) / k;
            for col in cols.clone() {
                let a = cy * cover(col as f64, x0, x1);
                let i = row * self.width + col;
                let old = f64::from(self.texels[i]);
                let new = f((col as f64 + 0.5) / k, y, old);
                self.texels[i] = (old + a * (new - old)) as f32;
            }
        }
    }

    /// Fills `rect` with a constant.
    pub fn fill_rect(&mut self, rect: Rect, value: f64) {
        self.paint_rect(rect, |_, _, _| value);
    }

    /// Draws the border of `rect`, `thickness_m` wide, inside it.
    pub fn frame(&mut self, rect: Rect, thickness_m: f64, value: f64) {
        let t = thickness_m;
        self.fill_rect(
            Rect {
                y1: rect.y0 + t,
                ..rect
            },
            value,
        );
        self.fill_rect(
            Rect {
                y0: rect.y1 - t,
                ..rect
            },
            value,
        );
        let middle = Rect {
            y0: rect.y0 + t,
            y1: rect.y1 - t,
            ..rect
        };
        self.fill_rect(
            Rect {
                x1: rect.x0 + t,
                ..middle
            },
            value,
        );
        self.fill_rect(
            Rect {
                x0: rect.x1 - t,
                ..middle
            },
            value,
        );
    }

    /// Fills a disk (center and radius in meters), anti-aliased.
    pub fn disk(&mut self, cx: f64, cy: f64, r: f64, value: f64) {
        let k = self.px_per_m;
        let bounds = Rect::new(
            cx - r - 1.0 / k,
            cy - r - 1.0 / k,
            2.0 * r + 2.0 / k,
            2.0 * r + 2.0 / k,
        );
        self.paint_rect(bounds, |x, y, old| {
            let d = ((x - cx) * (x - cx) + (y - cy) * (y - cy)).sqrt();
            let a = ((r - d) * k + 0.5).clamp(0.0, 1.0);
            old + a * (value - old)
        });
    }

    /// Clamps to 0..=255 and hands out the texture.
    pub fn into_texture(self) -> GrayTexture {
        GrayTexture {
            width: self.width as u32,
            height: self.height as u32,
            texels: self
                .texels
                .into_iter()
                .map(|t| t.clamp(0.0, 255.0))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix_reference_values() {
        // First outputs of SplitMix64 seeded with 1234567 (reference C code).
        let mut r = SplitMix64::new(1234567);
        assert_eq!(r.next_u64(), 6457827717110365317);
        assert_eq!(r.next_u64(), 3203168211198807973);
    }

    #[test]
    fn rng_ranges() {
        let mut r = SplitMix64::new(7);
        for _ in 0..1000 {
            let x = r.range(-2.0, 3.0);
            assert!((-2.0..3.0).contains(&x));
            assert!(r.below(5) < 5);
        }
        assert_eq!(r.below(0), 0);
    }

    #[test]
    fn noise_is_bounded_continuous_and_seeded() {
        let mut max_step: f64 = 0.0;
        for i in 0..2000 {
            let x = i as f64 * 0.013;
            let a = value_noise(3, x, 0.7 * x);
            assert!((-1.0..=1.0).contains(&a));
            max_step = max_step.max((value_noise(3, x + 1e-4, 0.7 * x) - a).abs());
        }
        assert!(max_step < 1e-3, "{max_step}");
        assert_ne!(value_noise(3, 0.5, 0.5), value_noise(4, 0.5, 0.5));
        let f = fbm(9, 1.3, 2.7, 0.5, 5, 0.6);
        assert!((-1.0..=1.0).contains(&f));
    }

    #[test]
    fn canvas_respects_budget() {
        let c = Canvas::new(50.0, 50.0, 1024.0);
        assert!(c.width * c.height <= MAX_TEXELS);
        assert!(c.width as u32 <= MAX_TEXTURE_SIDE);
        let (w, h) = c.size_m();
        assert!(w <= 50.0 + 1e-9 && h <= 50.0 + 1e-9 && w > 49.0);
    }

    #[test]
    fn rect_coverage_is_exact() {
        let mut c = Canvas::new(1.0, 1.0, 10.0);
        // Covers texel 2 fully and texel 3 half, one row.
        c.fill_rect(Rect::new(0.2, 0.0, 0.15, 0.1), 100.0);
        assert_eq!(c.texels[2], 100.0);
        assert!((c.texels[3] - 50.0).abs() < 1e-4);
        assert_eq!(c.texels[4], 0.0);
        assert_eq!(c.texels[c.width + 2], 0.0);
    }
}
