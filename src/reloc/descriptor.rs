//! The whole-image descriptor of relocalization: an 80x64 thumbnail,
//! blurred, its local mean subtracted, and 256 BRIEF-style pairwise
//! intensity comparisons on a fixed, seeded pattern, packed into `[u64; 4]`
//! and compared by Hamming distance.
//!
//! Takes an 8-bit camera frame or a rendered gray image of any size (area
//! resampled to the thumbnail); gives out a [`Descriptor`]. Comparisons are
//! invariant to gain and bias, the local-mean subtraction makes them
//! tolerant of slow shading (vignetting), and the blur of noise and of small
//! viewpoint changes.
//! All buffers live in [`Thumbnailer`], so computing a descriptor allocates
//! nothing after construction.

use crate::rng::SplitMix64;

/// Thumbnail width, pixels.
pub const THUMB_W: usize = 80;
/// Thumbnail height, pixels.
pub const THUMB_H: usize = 64;
/// Bits per descriptor.
pub const DESCRIPTOR_BITS: usize = 256;
/// Seed of the comparison pattern (part of the database format: changing it
/// changes every descriptor, so the database version must change too).
pub const PATTERN_SEED: u64 = 0x5354_4152_524c_4331;
/// Largest offset between the two pixels of a comparison, thumbnail pixels.
const MAX_PAIR_OFFSET: i64 = 32;
/// Smallest offset (L1) between the two pixels of a comparison.
const MIN_PAIR_OFFSET: i64 = 8;
/// Box radius of the blur, thumbnail pixels. Radius 3 (sigma 3.5 px) put
/// a keyframe within 0.5 m / 20 deg of the query among the 32 nearest by
/// Hamming distance for 93 of 100 `star bench reloc` queries (seed 1),
/// radius 2 (sigma 2.4 px) for 90 and radius 4 for 89: close-range views
/// a grid step off the query need the tolerance, wider blurs lose detail.
const BLUR_RADIUS: i64 = 3;
/// Box blur passes (3 passes of radius 3: about a Gaussian of sigma 3.5 px).
const BLUR_PASSES: usize = 3;
/// Radius of the box blur (3 passes, about a Gaussian of sigma 10 px) whose
/// output is subtracted from the thumbnail as its local mean.
const LOCAL_MEAN_RADIUS: i64 = 10;
/// Border kept free of comparison pixels (blur and distortion edge effects).
const BORDER: i64 = 3;

/// Horizontal shifts at which the query descriptor is also computed,
/// thumbnail pixels (about 7 degrees each for the presets' lens): a view
/// that is a few degrees of yaw off a database view still matches, and the
/// best shift tells the alignment where to start.
pub const QUERY_SHIFTS_PX: [i32; 3] = [0, -7, 7];

/// A 256-bit binary descriptor of a whole image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct Descriptor(pub [u64; 4]);

impl Descriptor {
    /// Number of differing bits.
    #[inline(always)]
    pub fn hamming(&self, other: &Descriptor) -> u32 {
        (self.0[0] ^ other.0[0]).count_ones()
            + (self.0[1] ^ other.0[1]).count_ones()
            + (self.0[2] ^ other.0[2]).count_ones()
            + (self.0[3] ^ other.0[3]).count_ones()
    }
}

/// Computes descriptors; owns the thumbnail buffers and the pattern.
#[derive(Debug, Clone)]
pub struct Thumbnailer {
    thumb: Vec<f32>,
    blurred: Vec<f32>,
    tmp: Vec<f32>,
    tmp2: Vec<f32>,
    mask: Vec<f32>,
    pairs: Vec<(u16, u16)>,
    /// For camera frames with lens distortion: where each pixel of the
    /// pinhole thumbnail lies in the raw thumbnail (thumbnail pixels).
    undistort: Option<Vec<[f32; 2]>>,
}

impl Default for Thumbnailer {
    fn default() -> Self {
        Self::new()
    }
}

impl Thumbnailer {
    /// Allocates the buffers and draws the fixed comparison pattern.
    pub fn new() -> Self {
        let mut rng = SplitMix64::new(PATTERN_SEED);
        let mut pairs = Vec::with_capacity(DESCRIPTOR_BITS);
        let (w, h) = (THUMB_W as i64, THUMB_H as i64);
        while pairs.len() < DESCRIPTOR_BITS {
            let x0 = BORDER + rng.below((w - 2 * BORDER) as usize) as i64;
            let y0 = BORDER + rng.below((h - 2 * BORDER) as usize) as i64;
            let dx = rng.below((2 * MAX_PAIR_OFFSET + 1) as usize) as i64 - MAX_PAIR_OFFSET;
            let dy = rng.below((2 * MAX_PAIR_OFFSET + 1) as usize) as i64 - MAX_PAIR_OFFSET;
            let (x1, y1) = (x0 + dx, y0 + dy);
            if x1 < BORDER || y1 < BORDER || x1 >= w - BORDER || y1 >= h - BORDER {
                continue;
            }
            if dx.abs() + dy.abs() < MIN_PAIR_OFFSET {
                continue;
            }
            pairs.push(((y0 * w + x0) as u16, (y1 * w + x1) as u16));
        }
        Self {
            thumb: vec![0.0; THUMB_W * THUMB_H],
            blurred: vec![0.0; THUMB_W * THUMB_H],
            tmp: vec![0.0; THUMB_W * THUMB_H],
            tmp2: vec![0.0; THUMB_W * THUMB_H],
            mask: vec![0.0; THUMB_W * THUMB_H],
            pairs,
            undistort: None,
        }
    }

    /// A thumbnailer for raw frames of `camera`: [`Self::describe_u8`]
    /// undistorts the thumbnail to the pinhole model of the database renders
    /// (at the presets' k1 = -0.1 the corners move by 4 thumbnail pixels).
    pub fn for_camera(camera: &crate::geometry::PinholeCamera) -> Self {
        let mut t = Self::new();
        if camera.distortion.is_zero() {
            return t;
        }
        let (w, h) = (camera.width as f64, camera.height as f64);
        let (sx, sy) = (THUMB_W as f64 / w, THUMB_H as f64 / h);
        let mut map = Vec::with_capacity(THUMB_W * THUMB_H);
        for ty in 0..THUMB_H {
            for tx in 0..THUMB_W {
                // Thumbnail pixel center -> full-resolution pinhole pixel.
                let u = (tx as f64 + 0.5) / sx - 0.5;
                let v = (ty as f64 + 0.5) / sy - 0.5;
                let xn = nalgebra::Vector2::new(
                    (u - camera.cx) / camera.fx,
                    (v - camera.cy) / camera.fy,
                );
                let xd = camera.distortion.distort(xn);
                let (ud, vd) = (camera.fx * xd.x + camera.cx, camera.fy * xd.y + camera.cy);
                map.push([
                    ((ud + 0.5) * sx - 0.5) as f32,
                    ((vd + 0.5) * sy - 0.5) as f32,
                ]);
            }
        }
        t.undistort = Some(map);
        t
    }

    /// The last thumbnail (before blurring), row-major `THUMB_W x THUMB_H`.
    pub fn thumbnail(&self) -> &[f32] {
        &self.thumb
    }

    /// Descriptor of an 8-bit gray image with row stride `stride`. `None`
    /// when the image is too small or has too little contrast (standard
    /// deviation of the thumbnail below `min_std`, e.g. a black frame).
    pub fn describe_u8(
        &mut self,
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        min_std: f32,
    ) -> Option<Descriptor> {
        if width < THUMB_W || height < THUMB_H || stride < width {
            return None;
        }
        if pixels.len() < stride * (height - 1) + width {
            return None;
        }
        area_resample(&mut self.thumb, width, height, |x, y| {
            pixels[y * stride + x] as f32
        });
        if let Some(map) = &self.undistort {
            let raw = &self.thumb;
            let at = |x: i64, y: i64| {
                let xc = x.clamp(0, THUMB_W as i64 - 1) as usize;
                let yc = y.clamp(0, THUMB_H as i64 - 1) as usize;
                raw[yc * THUMB_W + xc]
            };
            for (out, &[x, y]) in self.tmp2.iter_mut().zip(map) {
                let (x0, y0) = (x.floor(), y.floor());
                let (fx, fy) = (x - x0, y - y0);
                let (xi, yi) = (x0 as i64, y0 as i64);
                let top = at(xi, yi) * (1.0 - fx) + at(xi + 1, yi) * fx;
                let bottom = at(xi, yi + 1) * (1.0 - fx) + at(xi + 1, yi + 1) * fx;
                *out = top * (1.0 - fy) + bottom * fy;
            }
            std::mem::swap(&mut self.thumb, &mut self.tmp2);
        }
        self.finish(min_std)
    }

    /// Descriptor of a gray image stored as `f32` row-major `width x height`.
    /// With `depth_m`, pixels without depth (map holes, unmapped space) are
    /// filled from their valid neighbourhood instead of counting as black.
    pub fn describe_f32(
        &mut self,
        gray: &[f32],
        depth_m: Option<&[f32]>,
        width: usize,
        height: usize,
        min_std: f32,
    ) -> Option<Descriptor> {
        if width < THUMB_W / 2 || height < THUMB_H / 2 || gray.len() < width * height {
            return None;
        }
        let Some(depth) = depth_m.filter(|d| d.len() >= width * height) else {
            area_resample(&mut self.thumb, width, height, |x, y| gray[y * width + x]);
            return self.finish(min_std);
        };
        let hit = |x: usize, y: usize| crate::render::RenderedView::is_hit(depth[y * width + x]);
        // Normalized convolution: blur(gray * mask) / blur(mask).
        area_resample(&mut self.thumb, width, height, |x, y| {
            if hit(x, y) {
                gray[y * width + x]
            } else {
                0.0
            }
        });
        area_resample(&mut self.mask, width, height, |x, y| {
            if hit(x, y) {
                1.0
            } else {
                0.0
            }
        });
        let mut wide_v = std::mem::take(&mut self.blurred);
        let mut wide_m = std::mem::take(&mut self.tmp2);
        blur(&self.thumb, &mut wide_v, &mut self.tmp, BLUR_RADIUS, 4);
        blur(&self.mask, &mut wide_m, &mut self.tmp, BLUR_RADIUS, 4);
        for (i, v) in self.thumb.iter_mut().enumerate() {
            let m = self.mask[i];
            if m < 0.999 {
                let fill = if wide_m[i] > 1e-3 {
                    wide_v[i] / wide_m[i]
                } else {
                    0.0
                };
                // The valid part of the pixel keeps its value.
                *v += (1.0 - m) * fill;
            }
        }
        self.blurred = wide_v;
        self.tmp2 = wide_m;
        self.finish(min_std)
    }

    /// The descriptor of the last image with its comparison pattern moved
    /// `dx` thumbnail pixels to the right (clamped at the borders).
    pub fn shifted(&self, dx: i32) -> Descriptor {
        let w = THUMB_W as i32;
        let mut bits = [0u64; 4];
        let at = |i: u16| {
            let (x, y) = (i as i32 % w, i as i32 / w);
            let xs = (x + dx).clamp(0, w - 1);
            self.blurred[(y * w + xs) as usize]
        };
        for (i, &(a, b)) in self.pairs.iter().enumerate() {
            if at(a) < at(b) {
                bits[i / 64] |= 1 << (i % 64);
            }
        }
        Descriptor(bits)
    }

    fn finish(&mut self, min_std: f32) -> Option<Descriptor> {
        let n = self.thumb.len() as f32;
        let mean = self.thumb.iter().sum::<f32>() / n;
        let var = self
            .thumb
            .iter()
            .map(|v| (v - mean) * (v - mean))
            .sum::<f32>()
            / n;
        if !(var.is_finite() && var.sqrt() >= min_std) {
            return None;
        }
        blur(
            &self.thumb,
            &mut self.blurred,
            &mut self.tmp,
            BLUR_RADIUS,
            BLUR_PASSES,
        );
        // Subtract the local mean: comparisons then see structure, not slow
        // shading (vignetting, a lamp's falloff) that the renders of the map
        // do not have. Measured on `star bench reloc`: whole-map success
        // 62 -> 66 %, 2 m window 67 -> 69 %.
        // (`mask` is free here: `describe_f32` is done with it.)
        blur(
            &self.blurred,
            &mut self.mask,
            &mut self.tmp,
            LOCAL_MEAN_RADIUS,
            3,
        );
        for (v, m) in self.blurred.iter_mut().zip(&self.mask) {
            *v -= m;
        }
        let mut bits = [0u64; 4];
        for (i, &(a, b)) in self.pairs.iter().enumerate() {
            let (va, vb) = (self.blurred[a as usize], self.blurred[b as usize]);
            if va < vb {
                bits[i / 64] |= 1 << (i % 64);
            }
        }
        Some(Descriptor(bits))
    }
}

/// Area resampling of a `width x height` image (read through `at`) into the
/// `THUMB_W x THUMB_H` buffer `out`: each thumbnail pixel averages the
/// source pixels whose centers fall in its footprint (point sampling when
/// the source is smaller than the thumbnail).
fn area_resample(out: &mut [f32], width: usize, height: usize, at: impl Fn(usize, usize) -> f32) {
    for ty in 0..THUMB_H {
        let y0 = ty * height / THUMB_H;
        let y1 = ((ty + 1) * height / THUMB_H).max(y0 + 1).min(height);
        for tx in 0..THUMB_W {
            let x0 = tx * width / THUMB_W;
            let x1 = ((tx + 1) * width / THUMB_W).max(x0 + 1).min(width);
            let mut sum = 0.0f32;
            for y in y0..y1 {
                for x in x0..x1 {
                    sum += at(x, y);
                }
            }
            out[ty * THUMB_W + tx] = sum / ((y1 - y0) * (x1 - x0)) as f32;
        }
    }
}

/// Separable box blur of radius [`BLUR_RADIUS`], [`BLUR_PASSES`] times
/// (about a Gaussian), clamped at the borders; `tmp` is scratch.
fn blur(input: &[f32], out: &mut [f32], tmp: &mut [f32], r: i64, passes: usize) {
    let (w, h) = (THUMB_W, THUMB_H);
    let norm = 1.0 / (2 * r + 1) as f32;
    out.copy_from_slice(input);
    // Running sums along each row, then each column: O(1) per pixel at any
    // radius, borders clamped (the edge pixel repeats).
    let box_1d = |src: &[f32], dst: &mut [f32], n: usize, stride: usize| {
        let at = |i: i64| src[i.clamp(0, n as i64 - 1) as usize * stride];
        let mut sum: f32 = (-r..=r).map(at).sum();
        for i in 0..n as i64 {
            dst[i as usize * stride] = sum * norm;
            sum += at(i + r + 1) - at(i - r);
        }
    };
    for _ in 0..passes {
        for y in 0..h {
            box_1d(&out[y * w..], &mut tmp[y * w..], w, 1);
        }
        for x in 0..w {
            box_1d(&tmp[x..], &mut out[x..], h, w);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_sum_blur_matches_the_direct_box_filter() {
        let (w, h) = (THUMB_W as i64, THUMB_H as i64);
        let input: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 251) as f32).collect();
        for (r, passes) in [(BLUR_RADIUS, 1), (LOCAL_MEAN_RADIUS, 2)] {
            let (mut out, mut tmp) = (vec![0.0; input.len()], vec![0.0; input.len()]);
            blur(&input, &mut out, &mut tmp, r, passes);
            let mut direct = input.clone();
            let clamp = |v: i64, n: i64| v.clamp(0, n - 1);
            for _ in 0..passes {
                let mut rows = vec![0.0f32; direct.len()];
                for y in 0..h {
                    for x in 0..w {
                        let s: f32 = (-r..=r)
                            .map(|d| direct[(y * w + clamp(x + d, w)) as usize])
                            .sum();
                        rows[(y * w + x) as usize] = s / (2 * r + 1) as f32;
                    }
                }
                for y in 0..h {
                    for x in 0..w {
                        let s: f32 = (-r..=r)
                            .map(|d| rows[(clamp(y + d, h) * w + x) as usize])
                            .sum();
                        direct[(y * w + x) as usize] = s / (2 * r + 1) as f32;
                    }
                }
            }
            for (a, b) in out.iter().zip(&direct) {
                assert!((a - b).abs() < 1e-2, "radius {r}: {a} vs {b}");
            }
        }
    }

    fn pattern(w: usize, h: usize, phase: f32) -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let v = 128.0
                    + 60.0 * (x * 0.031 + phase).sin()
                    + 50.0 * (y * 0.047 - 0.5 * phase).cos()
                    + 30.0 * ((x + y) * 0.013 + phase * 2.0).sin();
                v.clamp(0.0, 255.0) as u8
            })
            .collect()
    }

    #[test]
    fn descriptor_is_deterministic_and_photometrically_invariant() {
        let img = pattern(640, 512, 0.0);
        let mut a = Thumbnailer::new();
        let mut b = Thumbnailer::new();
        let da = a.describe_u8(&img, 640, 512, 640, 2.0).expect("contrast");
        let db = b.describe_u8(&img, 640, 512, 640, 2.0).expect("contrast");
        assert_eq!(da, db);
        assert_eq!(da.hamming(&db), 0);
        // Gain and bias change no comparison (ties aside).
        let brighter: Vec<u8> = img.iter().map(|&v| (v as f32 * 0.8 + 20.0) as u8).collect();
        let dc = a
            .describe_u8(&brighter, 640, 512, 640, 2.0)
            .expect("contrast");
        assert!(da.hamming(&dc) < 8, "{}", da.hamming(&dc));
    }

    #[test]
    fn hamming_ranks_similar_views_first() {
        let mut t = Thumbnailer::new();
        let base = t
            .describe_u8(&pattern(640, 512, 0.0), 640, 512, 640, 2.0)
            .expect("base");
        let near = t
            .describe_u8(&pattern(640, 512, 0.1), 640, 512, 640, 2.0)
            .expect("near");
        let far = t
            .describe_u8(&pattern(640, 512, 2.0), 640, 512, 640, 2.0)
            .expect("far");
        assert!(base.hamming(&near) < base.hamming(&far));
        assert!(base.hamming(&far) > 40, "{}", base.hamming(&far));
        assert_eq!(Descriptor([u64::MAX; 4]).hamming(&Descriptor([0; 4])), 256);
    }

    #[test]
    fn flat_or_small_frames_have_no_descriptor() {
        let mut t = Thumbnailer::new();
        assert!(t
            .describe_u8(&[0u8; 640 * 512], 640, 512, 640, 2.0)
            .is_none());
        assert!(t.describe_u8(&[0u8; 10], 640, 512, 640, 2.0).is_none());
        assert!(t.describe_u8(&[7u8; 40 * 30], 40, 30, 40, 2.0).is_none());
    }

    #[test]
    fn u8_and_f32_inputs_agree() {
        let img = pattern(320, 256, 0.3);
        let f: Vec<f32> = img.iter().map(|&v| v as f32).collect();
        let mut t = Thumbnailer::new();
        let a = t.describe_u8(&img, 320, 256, 320, 2.0).expect("u8");
        let b = t.describe_f32(&f, None, 320, 256, 2.0).expect("f32");
        assert_eq!(a, b);
    }
}
