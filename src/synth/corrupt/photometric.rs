//! Photometric sensor model: `out = gain(t) * vignette(u, v) * in + bias(t)
//! + noise`, rounded and clamped to 8 bits.
//!
//! - gain and bias drift slowly: each is a sum of two sinusoids (periods
//!   drawn from [`PhotometricSpec::drift_period_s`]) with total amplitude
//!   `gain_drift` (relative) and `bias_drift` (gray levels);
//! - vignetting darkens quadratically with the distance from the principal
//!   point: `1 - vignetting * (r / r_corner)^2`, so the farthest corner keeps
//!   `1 - vignetting` of its brightness;
//! - noise is Gaussian with `noise_sigma` gray levels, drawn from a
//!   generator seeded per frame, so frames can be produced in any order.

use nalgebra::Vector2;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::Serialize;

use super::derive_seed;
use crate::geometry::PinholeCamera;
use crate::imgproc::{ImageF32, ImageU8};

/// Exact photometric parameters of a preset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PhotometricSpec {
    /// Peak relative gain excursion (0.3 = gain in 0.7..1.3).
    pub gain_drift: f64,
    /// Peak bias excursion, gray levels.
    pub bias_drift: f64,
    /// Range of the drift sinusoids' periods, seconds.
    pub drift_period_s: (f64, f64),
    /// Relative darkening at the farthest image corner (0 = none).
    pub vignetting: f64,
    /// Standard deviation of the additive Gaussian noise, gray levels.
    pub noise_sigma: f64,
}

impl PhotometricSpec {
    /// No corruption at all: unit gain, zero bias, no vignetting, no noise.
    pub const NONE: PhotometricSpec = PhotometricSpec {
        gain_drift: 0.0,
        bias_drift: 0.0,
        drift_period_s: (10.0, 30.0),
        vignetting: 0.0,
        noise_sigma: 0.0,
    };
}

/// A seeded slow drift of gain and bias over time.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotometricDrift {
    gain: [(f64, f64, f64); 2],
    bias: [(f64, f64, f64); 2],
}

fn draw(rng: &mut StdRng, amplitude: f64, (lo, hi): (f64, f64)) -> [(f64, f64, f64); 2] {
    let w: f64 = rng.random_range(0.3..0.7);
    let mut one = |a: f64| {
        let period_s: f64 = if hi > lo {
            rng.random_range(lo..hi)
        } else {
            lo.max(1e-3)
        };
        (
            a,
            std::f64::consts::TAU / period_s,
            rng.random_range(0.0..std::f64::consts::TAU),
        )
    };
    [one(amplitude * w), one(amplitude * (1.0 - w))]
}

fn eval(terms: &[(f64, f64, f64); 2], t_s: f64) -> f64 {
    terms
        .iter()
        .map(|(a, w, phase)| a * (w * t_s + phase).sin())
        .sum()
}

impl PhotometricDrift {
    /// Draws the drift of `spec` from `seed`.
    pub fn new(spec: &PhotometricSpec, seed: u64) -> Self {
        let mut rng = StdRng::seed_from_u64(derive_seed(seed, 0x9a1));
        Self {
            gain: draw(&mut rng, spec.gain_drift, spec.drift_period_s),
            bias: draw(&mut rng, spec.bias_drift, spec.drift_period_s),
        }
    }

    /// Gain at time `t_s`.
    pub fn gain_at(&self, t_s: f64) -> f64 {
        1.0 + eval(&self.gain, t_s)
    }

    /// Bias at time `t_s`, gray levels.
    pub fn bias_at(&self, t_s: f64) -> f64 {
        eval(&self.bias, t_s)
    }
}

/// The per-pixel sensor model, built once per sequence.
#[derive(Debug, Clone)]
pub struct SensorModel {
    spec: PhotometricSpec,
    drift: PhotometricDrift,
    vignette: ImageF32,
    seed: u64,
}

impl SensorModel {
    /// Precomputes the vignetting map for `camera` and draws the drift.
    pub fn new(spec: PhotometricSpec, camera: &PinholeCamera, seed: u64) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let center = Vector2::new(camera.cx, camera.cy);
        let r_corner = [
            (0.0, 0.0),
            (w as f64 - 1.0, 0.0),
            (0.0, h as f64 - 1.0),
            (w as f64 - 1.0, h as f64 - 1.0),
        ]
        .iter()
        .map(|&(x, y)| (Vector2::new(x, y) - center).norm())
        .fold(1e-9, f64::max);
        let mut vignette = ImageF32::new(w, h, 1.0);
        for y in 0..h {
            for (x, v) in vignette.row_mut(y).iter_mut().enumerate() {
                let rho = (Vector2::new(x as f64, y as f64) - center).norm() / r_corner;
                *v = (1.0 - spec.vignetting * rho * rho) as f32;
            }
        }
        Self {
            spec,
            drift: PhotometricDrift::new(&spec, seed),
            vignette,
            seed,
        }
    }

    /// The gain/bias drift.
    pub fn drift(&self) -> &PhotometricDrift {
        &self.drift
    }

    /// Applies the model to `input` (0..=255, camera-sized) for frame
    /// `frame_index` at time `t_s`, writing `out` (resized in place).
    pub fn apply(&self, input: &ImageF32, frame_index: u64, t_s: f64, out: &mut ImageU8) {
        out.resize(input.width(), input.height(), 0);
        let gain = self.drift.gain_at(t_s) as f32;
        let bias = self.drift.bias_at(t_s) as f32;
        let sigma = self.spec.noise_sigma as f32;
        let mut rng = StdRng::seed_from_u64(derive_seed(self.seed, frame_index.wrapping_add(1)));
        let mut spare: Option<f32> = None;
        let mut gaussian = || -> f32 {
            if let Some(z) = spare.take() {
                return z;
            }
            // Box-Muller: two uniforms give two independent standard normals.
            let u1: f32 = 1.0 - rng.random::<f32>(); // (0, 1]
            let u2: f32 = rng.random::<f32>();
            let r = (-2.0 * u1.ln()).sqrt();
            let (s, c) = (std::f32::consts::TAU * u2).sin_cos();
            spare = Some(r * s);
            r * c
        };
        let pixels = out
            .data_mut()
            .iter_mut()
            .zip(input.data())
            .zip(self.vignette.data());
        for ((o, &i), &v) in pixels {
            let noise = if sigma > 0.0 { sigma * gaussian() } else { 0.0 };
            *o = (gain * v * i + bias + noise).round().clamp(0.0, 255.0) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera::new(64, 48, 40.0, 40.0, 31.5, 23.5)
    }

    #[test]
    fn no_corruption_is_identity_rounding() {
        let model = SensorModel::new(PhotometricSpec::NONE, &camera(), 1);
        let input = ImageF32::from_vec(
            64,
            48,
            (0..64 * 48).map(|i| (i % 256) as f32 + 0.3).collect(),
        )
        .expect("size");
        let mut out = ImageU8::new(1, 1, 0);
        model.apply(&input, 3, 1.0, &mut out);
        assert_eq!(out, input.to_u8());
    }

    #[test]
    fn drift_stays_within_bounds_and_moves() {
        let spec = PhotometricSpec {
            gain_drift: 0.3,
            bias_drift: 10.0,
            ..PhotometricSpec::NONE
        };
        let drift = PhotometricDrift::new(&spec, 9);
        let gains: Vec<f64> = (0..600).map(|i| drift.gain_at(i as f64 * 0.1)).collect();
        let (lo, hi) = gains
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &g| (a.min(g), b.max(g)));
        assert!(lo >= 0.7 - 1e-12 && hi <= 1.3 + 1e-12, "{lo} {hi}");
        assert!(
            hi - lo > 0.2,
            "gain actually drifts over a minute: {lo}..{hi}"
        );
        assert!((0..600).all(|i| drift.bias_at(i as f64 * 0.1).abs() <= 10.0 + 1e-12));
        // Slow: less than 1 % gain change per 20 ms frame.
        assert!(gains.windows(2).all(|w| (w[1] - w[0]).abs() < 0.01 * 5.0));
        assert_eq!(drift, PhotometricDrift::new(&spec, 9));
    }

    #[test]
    fn vignetting_darkens_corners_only() {
        let spec = PhotometricSpec {
            vignetting: 0.4,
            ..PhotometricSpec::NONE
        };
        let model = SensorModel::new(spec, &camera(), 1);
        let mut out = ImageU8::new(1, 1, 0);
        model.apply(&ImageF32::new(64, 48, 200.0), 0, 0.0, &mut out);
        assert_eq!(out.get(31, 23), Some(200));
        let corner = out.get(0, 0).expect("inside");
        assert!((119..=121).contains(&corner), "corner {corner}");
    }

    #[test]
    fn noise_has_the_requested_sigma_and_is_seeded_per_frame() {
        let spec = PhotometricSpec {
            noise_sigma: 3.0,
            ..PhotometricSpec::NONE
        };
        let model = SensorModel::new(spec, &camera(), 5);
        let input = ImageF32::new(64, 48, 100.0);
        let (mut a, mut b, mut c) = (
            ImageU8::new(1, 1, 0),
            ImageU8::new(1, 1, 0),
            ImageU8::new(1, 1, 0),
        );
        model.apply(&input, 7, 0.0, &mut a);
        model.apply(&input, 8, 0.0, &mut b);
        model.apply(&input, 7, 0.0, &mut c);
        assert_eq!(a, c, "same frame, same noise");
        assert_ne!(a, b, "other frame, other noise");
        let n = a.data().len() as f64;
        let mean = a.data().iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = a
            .data()
            .iter()
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / n;
        assert!((mean - 100.0).abs() < 0.3, "mean {mean}");
        // Rounding adds 1/12 of a level squared.
        assert!((var.sqrt() - 3.0).abs() < 0.2, "sigma {}", var.sqrt());
    }
}
