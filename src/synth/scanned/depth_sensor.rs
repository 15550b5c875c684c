//! The scanning run's depth sensor: a structured-light camera's errors
//! applied to an ideal rendered depth image.
//!
//! Per pixel with a surface (in this order):
//! - out of range (closer than `min_range_m`, farther than `max_range_m`):
//!   no measurement;
//! - grazing angle: with `theta` the angle between the viewing ray and the
//!   surface normal, dropped with a probability rising linearly from 0 at
//!   `grazing_start_deg` to 1 at `grazing_end_deg`;
//! - depth edge (a 4-neighbour without depth or farther/closer by more than
//!   `edge_jump_m + edge_jump_per_m * z`): dropped with probability
//!   `edge_dropout` (the projector's shadow and the matcher's window);
//! - anywhere: dropped with probability `random_dropout`;
//! - kept: `z + N(0, sigma)` with `sigma = sigma_mm_per_m2 * z^2` (mm, z in
//!   m; Khoshelham and Elberink's Kinect model), rounded to
//!   `quantization_mm`, stored as 16-bit millimeters (0 = none).
//!
//! Draws come from a generator seeded per frame, so frames can be made in
//! any order.

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::Serialize;

use crate::geometry::PinholeCamera;
use crate::imgproc::ImageF32;

/// Exact depth-sensor parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DepthSensorSpec {
    /// Noise standard deviation per squared meter of depth, millimeters.
    pub sigma_mm_per_m2: f64,
    /// Depth quantization step, millimeters.
    pub quantization_mm: f64,
    /// Closest measured depth, meters.
    pub min_range_m: f64,
    /// Farthest measured depth, meters.
    pub max_range_m: f64,
    /// Ray-to-normal angle where grazing dropouts start, degrees.
    pub grazing_start_deg: f64,
    /// Ray-to-normal angle where every pixel is dropped, degrees.
    pub grazing_end_deg: f64,
    /// Depth step to a neighbour that makes a pixel an edge, meters ...
    pub edge_jump_m: f64,
    /// ... plus this much per meter of depth.
    pub edge_jump_per_m: f64,
    /// Probability that an edge pixel has no measurement.
    pub edge_dropout: f64,
    /// Probability that any pixel has no measurement.
    pub random_dropout: f64,
}

impl DepthSensorSpec {
    /// A structured-light RGB-D sensor (Kinect / RealSense class): the
    /// `scanned` preset's.
    pub const STRUCTURED_LIGHT: Self = Self {
        sigma_mm_per_m2: 1.5,
        quantization_mm: 1.0,
        min_range_m: 0.4,
        max_range_m: 4.0,
        grazing_start_deg: 70.0,
        grazing_end_deg: 85.0,
        edge_jump_m: 0.03,
        edge_jump_per_m: 0.01,
        edge_dropout: 0.7,
        random_dropout: 0.005,
    };
}

/// Gaussian draws by Box-Muller, two per pair of uniforms.
pub(super) struct Gaussian {
    rng: StdRng,
    spare: Option<f64>,
}

impl Gaussian {
    pub(super) fn new(seed: u64) -> Self {
        Self {
            rng: StdRng::seed_from_u64(seed),
            spare: None,
        }
    }

    pub(super) fn uniform(&mut self) -> f64 {
        self.rng.random::<f64>()
    }

    pub(super) fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        let u1 = 1.0 - self.rng.random::<f64>();
        let u2 = self.rng.random::<f64>();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
        self.spare = Some(r * s);
        r * c
    }
}

impl DepthSensorSpec {
    /// The measured depth image of `depth_m` (ideal, meters) as 16-bit
    /// millimeters into `out` (resized). `normals` from
    /// [`super::lighting::depth_normals`]; `seed` is this frame's.
    pub fn measure(
        &self,
        depth_m: &ImageF32,
        normals: &[[f32; 3]],
        camera: &PinholeCamera,
        seed: u64,
        out: &mut Vec<u16>,
    ) {
        let (w, h) = (depth_m.width(), depth_m.height());
        out.clear();
        out.resize(w * h, 0);
        let d = depth_m.data();
        let mut rng = Gaussian::new(seed);
        let cos_start = self.grazing_start_deg.to_radians().cos();
        let cos_end = self.grazing_end_deg.to_radians().cos();
        let q_m = self.quantization_mm.max(1e-3) * 1e-3;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let z = d[i] as f64;
                if !(z >= self.min_range_m && z <= self.max_range_m) {
                    continue;
                }
                // Draw the same number of variates per pixel so one pixel's
                // fate does not shift every later pixel's noise.
                let (u_grazing, u_edge, u_random, noise) =
                    (rng.uniform(), rng.uniform(), rng.uniform(), rng.normal());
                let ray = nalgebra::Vector3::new(
                    (x as f64 - camera.cx) / camera.fx,
                    (y as f64 - camera.cy) / camera.fy,
                    1.0,
                )
                .normalize();
                let n = normals[i];
                let cos = -(ray.x * n[0] as f64 + ray.y * n[1] as f64 + ray.z * n[2] as f64);
                let p_grazing = if cos >= cos_start {
                    0.0
                } else if cos <= cos_end {
                    1.0
                } else {
                    (cos_start - cos) / (cos_start - cos_end)
                };
                if u_grazing < p_grazing {
                    continue;
                }
                let jump = self.edge_jump_m + self.edge_jump_per_m * z;
                let neighbours = [
                    (x > 0).then(|| d[i - 1]),
                    (x + 1 < w).then(|| d[i + 1]),
                    (y > 0).then(|| d[i - w]),
                    (y + 1 < h).then(|| d[i + w]),
                ];
                let edge = neighbours
                    .iter()
                    .flatten()
                    .any(|&n| n <= 0.0 || (n as f64 - z).abs() > jump);
                if (edge && u_edge < self.edge_dropout) || u_random < self.random_dropout {
                    continue;
                }
                let sigma_m = self.sigma_mm_per_m2 * z * z * 1e-3;
                let measured = ((z + sigma_m * noise) / q_m).round() * q_m;
                out[i] = (measured * 1000.0).round().clamp(0.0, u16::MAX as f64) as u16;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> DepthSensorSpec {
        DepthSensorSpec::STRUCTURED_LIGHT
    }

    fn camera() -> PinholeCamera {
        PinholeCamera::new(64, 48, 40.0, 40.0, 31.5, 23.5)
    }

    #[test]
    fn noise_grows_with_depth_squared_and_range_is_cut() {
        let cam = camera();
        let normals = vec![[0.0f32, 0.0, -1.0]; 64 * 48];
        let mut out = Vec::new();
        for (z, sigma_mm) in [(1.0f32, 1.5), (3.0, 13.5)] {
            let depth = ImageF32::new(64, 48, z);
            let mut values = Vec::new();
            for frame in 0..4 {
                spec().measure(&depth, &normals, &cam, frame, &mut out);
                values.extend(out.iter().filter(|&&v| v > 0).map(|&v| v as f64));
            }
            let n = values.len() as f64;
            let mean = values.iter().sum::<f64>() / n;
            let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
            assert!((mean - 1000.0 * z as f64).abs() < 1.0, "z {z}: mean {mean}");
            assert!(
                (sd - sigma_mm).abs() < 0.15 * sigma_mm + 0.3,
                "z {z}: sd {sd}"
            );
            assert!(n > 0.98 * 4.0 * 64.0 * 48.0, "few random dropouts: {n}");
        }
        spec().measure(&ImageF32::new(64, 48, 4.5), &normals, &cam, 0, &mut out);
        assert!(out.iter().all(|&v| v == 0), "beyond range");
    }

    #[test]
    fn grazing_surfaces_and_edges_drop_out() {
        // A narrow field of view: every ray is close to the optical axis.
        let cam = PinholeCamera::new(64, 48, 4000.0, 4000.0, 31.5, 23.5);
        // Seen at 80 degrees: two thirds dropped.
        let n80 = [
            -(80f32.to_radians().sin()),
            0.0,
            -(80f32.to_radians().cos()),
        ];
        let normals = vec![n80; 64 * 48];
        let mut depth = ImageF32::new(64, 48, 2.0);
        let mut out = Vec::new();
        spec().measure(&depth, &normals, &cam, 1, &mut out);
        let kept = out.iter().filter(|&&v| v > 0).count() as f64 / out.len() as f64;
        assert!((0.28..0.4).contains(&kept), "kept {kept}");
        // A step from 2 m to 3 m at column 32: both sides of it are edges.
        let normals = vec![[0.0f32, 0.0, -1.0]; 64 * 48];
        for y in 0..48 {
            depth.row_mut(y)[32..].fill(3.0);
        }
        let (mut dropped, mut total) = (0, 0);
        for frame in 0..8 {
            spec().measure(&depth, &normals, &cam, frame, &mut out);
            for y in 0..48 {
                total += 2;
                dropped += (out[y * 64 + 31] == 0) as usize + (out[y * 64 + 32] == 0) as usize;
            }
        }
        let rate = dropped as f64 / total as f64;
        assert!((0.6..0.8).contains(&rate), "edge dropout {rate}");
    }
}
