//! Per-frame direct alignment of a camera image against a prepared keyframe.
//!
//! Inverse compositional Levenberg-Marquardt on SE(3) plus a photometric
//! model, coarse to fine. Residual of keyframe point `i`:
//! `r_i = I_cam(pi_dist(K T_ck p_i)) - (a * I_ref_i + b)` (affine model) or
//! `r_i = I_cam(...) - I_ref_i - beta` with `beta` the median offset (the
//! paper's model). Huber weights with a scale estimated once per level from
//! the median absolute residual, and a hard cut for gross outliers
//! (occluders, unmapped regions). The keyframe side is an ideal pinhole
//! render; lens distortion is applied in the warp into the raw camera image,
//! so frames are never undistorted.
//!
//! The Jacobian of each point is precomputed at keyframe preparation
//! (inverse compositional); the update is `T_ck <- T_ck * exp(delta)^-1`.
//! All buffers are allocated by [`Aligner::new`]; [`Aligner::align`] does not
//! allocate.

use nalgebra::Vector6;

use crate::geometry::{exp_se3, renormalized, PinholeCamera, Pose};
use crate::track::{IlluminationModel, TrackerConfig};

use super::keyframe::Keyframe;
use super::normal_eq::{Accumulator6, NormalEquations};
use super::pyramid::Pyramid;

/// Maximum number of pyramid levels.
pub const MAX_LEVELS: usize = 6;

/// A pose increment (`|[v; w]|`, meters and radians) below which a rejected
/// LM step ends the level.
const STEP_CONVERGED: f64 = 1e-3;

/// Quality of one alignment, computed at the finest level.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AlignQuality {
    /// Fraction of visible points whose residual is below the inlier threshold.
    pub inlier_ratio: f32,
    /// Fraction of finest-level keyframe points that project into the image.
    pub visible_ratio: f32,
    /// RMS residual of the inliers, gray levels.
    pub residual_rms: f32,
    /// Zero-mean normalized cross-correlation between the keyframe
    /// intensities and the camera samples over the visible points (-1..=1).
    /// Invariant to gain and bias; near 1 when aligned, near 0 when the
    /// frame shows something else, however many residuals fall under the
    /// inlier threshold by chance.
    pub correlation: f32,
    /// Points used (visible) per level, finest first.
    pub points_used: [u32; MAX_LEVELS],
    /// Total LM iterations over all levels.
    pub iterations: u32,
}

/// Result of aligning one frame.
#[derive(Debug, Clone, Copy)]
pub struct Alignment {
    /// Estimated pose of the camera relative to the keyframe.
    pub camera_from_keyframe: Pose,
    /// Photometric gain `a` (1 for the median model).
    pub gain: f32,
    /// Photometric bias `b`, or the median offset `beta`.
    pub bias: f32,
    /// Covariance of the final inverse-compositional increment `delta`
    /// (`[v; w]`, keyframe frame), inverse Hessian scaled by the residual variance.
    pub covariance_delta: [[f64; 6]; 6],
    /// Quality figures.
    pub quality: AlignQuality,
    /// False when the finest level could not be evaluated or the solution is
    /// degenerate (not finite, gain out of range).
    pub valid: bool,
}

/// Reusable alignment state and scratch buffers.
#[derive(Debug, Clone)]
pub struct Aligner {
    warped: Vec<f32>,
    config: TrackerConfig,
}

/// What a level's first evaluation estimates and its LM iterations reuse.
#[derive(Debug, Clone, Copy, Default)]
struct LevelScale {
    /// Huber scale, gray levels.
    huber_k: Option<f32>,
    /// Median and MAD of the visible keyframe intensities (affine model).
    reference: Option<(f32, f32)>,
}

#[derive(Debug, Clone, Copy)]
struct Eval {
    ne: NormalEquations,
    energy: f64,
    visible: usize,
    inliers: usize,
    inlier_sq_sum: f64,
    correlation: f32,
    gain: f32,
    bias: f32,
}

impl Aligner {
    /// Allocates scratch for the configured maximum number of points.
    pub fn new(config: &TrackerConfig) -> Self {
        let cap = config.max_points_per_level(0);
        Self {
            warped: vec![0.0; cap],
            config: config.clone(),
        }
    }

    /// Aligns `frame` (pyramid of the raw camera image, `camera` with its
    /// distortion) against `keyframe`, starting from `camera_from_keyframe`.
    /// The photometric parameters are re-estimated at every evaluation.
    pub fn align(
        &mut self,
        keyframe: &Keyframe,
        frame: &Pyramid,
        camera: &PinholeCamera,
        camera_from_keyframe: Pose,
    ) -> Alignment {
        self.align_to_level(keyframe, frame, camera, camera_from_keyframe, 0)
    }

    /// [`Self::align`], stopping at pyramid level `finest_level` (0 is full
    /// resolution); the quality and covariance are those of that level.
    /// Relocalization runs many cheap coarse alignments from different
    /// starts and finishes only the best at full resolution.
    pub fn align_to_level(
        &mut self,
        keyframe: &Keyframe,
        frame: &Pyramid,
        camera: &PinholeCamera,
        camera_from_keyframe: Pose,
        finest_level: usize,
    ) -> Alignment {
        self.align_levels(
            keyframe,
            frame,
            camera,
            camera_from_keyframe,
            finest_level,
            0,
        )
    }

    /// [`Self::align`] without the `skip_coarsest` coarsest levels (at
    /// least one level is kept). Relocalization builds its pyramids one
    /// level coarser than tracking, for the wider basin its database views
    /// need; a start already within a few centimeters (the landmark pose,
    /// a render at an aligned pose) has no use for it, and there an
    /// unmapped object that fills a fifth of the view outweighs the map
    /// at 40x32 pixels.
    pub fn align_without_coarsest(
        &mut self,
        keyframe: &Keyframe,
        frame: &Pyramid,
        camera: &PinholeCamera,
        camera_from_keyframe: Pose,
        skip_coarsest: usize,
    ) -> Alignment {
        self.align_levels(
            keyframe,
            frame,
            camera,
            camera_from_keyframe,
            0,
            skip_coarsest,
        )
    }

    /// Coarse to fine, from the coarsest level less `skip_coarsest` down to
    /// `finest_level`.
    fn align_levels(
        &mut self,
        keyframe: &Keyframe,
        frame: &Pyramid,
        camera: &PinholeCamera,
        camera_from_keyframe: Pose,
        finest_level: usize,
        skip_coarsest: usize,
    ) -> Alignment {
        let all_levels = keyframe
            .levels
            .len()
            .min(frame.len())
            .min(self.config.pyramid_levels as usize)
            .min(MAX_LEVELS);
        let n_levels = all_levels
            .saturating_sub(skip_coarsest)
            .max(1)
            .min(all_levels);
        let mut pose = camera_from_keyframe;
        let (mut a, mut b) = (1.0f32, 0.0f32);
        let mut quality = AlignQuality::default();
        let mut final_eval: Option<Eval> = None;
        let finest_level = finest_level.min(n_levels.saturating_sub(1));
        for level in (finest_level..n_levels).rev() {
            let n_points = keyframe.levels[level].points.len();
            if n_points < self.config.min_points as usize {
                continue;
            }
            let cam_l = camera.scaled_to_level(level as u32);
            let mut scale = LevelScale::default();
            let Some(first) = self.evaluate(keyframe, frame, &cam_l, level, &pose, &mut scale)
            else {
                continue;
            };
            let mut cur = first;
            let mut lambda = 0.0f64;
            for _ in 0..self.config.max_iterations {
                quality.iterations += 1;
                let Some(step) = cur.ne.solve(lambda) else {
                    break;
                };
                if step.iter().any(|v| !v.is_finite()) {
                    break;
                }
                let delta = Vector6::new(step[0], step[1], step[2], step[3], step[4], step[5]);
                let cand_pose = renormalized(pose * exp_se3(&delta).inverse());
                let cand = self.evaluate(keyframe, frame, &cam_l, level, &cand_pose, &mut scale);
                match cand {
                    Some(e) if e.energy <= cur.energy => {
                        pose = cand_pose;
                        let rel = (cur.energy - e.energy) / cur.energy.max(1e-12);
                        cur = e;
                        lambda = if lambda > 0.0 { lambda * 0.25 } else { 0.0 };
                        if lambda < 1e-4 {
                            lambda = 0.0;
                        }
                        if delta.norm() < 1e-4 || rel < 1e-4 {
                            break;
                        }
                    }
                    _ => {
                        // A rejected step this small means the minimum is
                        // reached and the energy is at its noise floor;
                        // damping it further only burns evaluations.
                        if delta.norm() < STEP_CONVERGED {
                            break;
                        }
                        lambda = if lambda == 0.0 { 1e-3 } else { lambda * 8.0 };
                        if lambda > 1e3 {
                            break;
                        }
                    }
                }
            }
            quality.points_used[level] = cur.visible as u32;
            a = cur.gain;
            b = cur.bias;
            if level == finest_level {
                final_eval = Some(cur);
            }
        }
        let mut result = Alignment {
            camera_from_keyframe: pose,
            gain: a,
            bias: b,
            covariance_delta: [[0.0; 6]; 6],
            quality,
            valid: false,
        };
        let Some(e) = final_eval else {
            return result;
        };
        let n0 = keyframe.levels[finest_level].points.len().max(1);
        result.quality.visible_ratio = e.visible as f32 / n0 as f32;
        result.quality.inlier_ratio = e.inliers as f32 / e.visible.max(1) as f32;
        result.quality.residual_rms = (e.inlier_sq_sum / e.inliers.max(1) as f64).sqrt() as f32;
        result.quality.correlation = e.correlation;
        let dof = (e.ne.count as f64 - e.ne.n as f64).max(1.0);
        // The residual variance per degree of freedom, and the benches'
        // factor for the residuals' correlation (`covariance_scale`).
        let sigma_sq = e.ne.weighted_sq_sum / dof * self.config.covariance_scale;
        if let Some(inv) = e.ne.inverse() {
            for (r, row) in result.covariance_delta.iter_mut().enumerate() {
                for (c, v) in row.iter_mut().enumerate() {
                    *v = inv[r][c] * sigma_sq;
                }
            }
        }
        let t = pose.translation.vector;
        let finite = t.iter().all(|v| v.is_finite())
            && pose.rotation.coords.iter().all(|v| v.is_finite())
            && a.is_finite()
            && b.is_finite();
        result.valid = finite && (0.2..=5.0).contains(&a) && e.visible > 0;
        result
    }

    /// Warps, samples and accumulates one level. The first evaluation of a
    /// level estimates the Huber scale and the keyframe side's photometric
    /// statistics into `scale`; later ones reuse them.
    #[allow(clippy::too_many_arguments)]
    fn evaluate(
        &mut self,
        keyframe: &Keyframe,
        frame: &Pyramid,
        camera: &PinholeCamera,
        level: usize,
        camera_from_keyframe: &Pose,
        scale: &mut LevelScale,
    ) -> Option<Eval> {
        let model = self.config.illumination;
        let points = &keyframe.levels[level].points;
        let image = frame.level(level);
        let m = camera_from_keyframe.to_homogeneous();
        let r = [
            [m[(0, 0)] as f32, m[(0, 1)] as f32, m[(0, 2)] as f32],
            [m[(1, 0)] as f32, m[(1, 1)] as f32, m[(1, 2)] as f32],
            [m[(2, 0)] as f32, m[(2, 1)] as f32, m[(2, 2)] as f32],
        ];
        let t = [m[(0, 3)] as f32, m[(1, 3)] as f32, m[(2, 3)] as f32];
        let (fx, fy, cx, cy) = (
            camera.fx as f32,
            camera.fy as f32,
            camera.cx as f32,
            camera.cy as f32,
        );
        let dist = camera.distortion;
        let distorted = !dist.is_zero();
        let (k1, k2, k3, p1, p2) = (
            dist.k1 as f32,
            dist.k2 as f32,
            dist.k3 as f32,
            dist.p1 as f32,
            dist.p2 as f32,
        );
        let max_u = image.width() as f32 - 1.001;
        let max_v = image.height() as f32 - 1.001;
        let warped = &mut self.warped[..points.len()];
        // Pass 1: warp and sample.
        let mut visible = 0usize;
        for (pt, out) in points.iter().zip(warped.iter_mut()) {
            let p = pt.p_keyframe;
            let z = r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + t[2];
            *out = f32::NAN;
            if !(z > 1e-3) {
                continue;
            }
            let inv_z = 1.0 / z;
            let mut xn = (r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + t[0]) * inv_z;
            let mut yn = (r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + t[1]) * inv_z;
            if distorted {
                let r2 = xn * xn + yn * yn;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let dx = 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn);
                let dy = p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn;
                xn = xn * radial + dx;
                yn = yn * radial + dy;
            }
            let u = fx * xn + cx;
            let v = fy * yn + cy;
            if !(u >= 0.0 && v >= 0.0 && u < max_u && v < max_v) {
                continue;
            }
            if let Some(val) = image.bilinear(u, v) {
                *out = val;
                visible += 1;
            }
        }
        if visible < self.config.min_points as usize {
            return None;
        }
        // Photometric model from the current correspondences: the median
        // offset, or a robust moment match (median and MAD) for gain and
        // bias. Moment matching does not shrink the gain under misalignment,
        // which a joint least-squares fit of the gain does.
        let (a, b) = self.photometric(points, model, &mut scale.reference);
        let warped = &self.warped[..points.len()];
        let huber_min_gray = self.config.huber_min_gray;
        let k = *scale.huber_k.get_or_insert_with(|| {
            let abs_residuals = points
                .iter()
                .zip(warped)
                .filter(|(_, wv)| !wv.is_nan())
                .map(|(pt, &wv)| (wv - (a * pt.gray + b)).abs());
            (1.345 * 1.4826 * approx_median_of(abs_residuals, 0.0, 256.0)).max(huber_min_gray)
        });
        let cut = (4.0 * k).max(self.config.outlier_cut_gray);
        let rho_cut = k * (cut - 0.5 * k);
        let mut acc = Accumulator6::default();
        let mut energy = 0.0f64;
        let mut inliers = 0usize;
        let mut inlier_sq_sum = 0.0f64;
        let inlier_th = self.config.inlier_threshold_gray;
        let mut moments = [0.0f64; 5];
        for (pt, &wv) in points.iter().zip(warped.iter()) {
            if wv.is_nan() {
                energy += rho_cut as f64;
                continue;
            }
            let (x, y) = (pt.gray as f64, wv as f64);
            moments[0] += x;
            moments[1] += y;
            moments[2] += x * x;
            moments[3] += y * y;
            moments[4] += x * y;
            let res = wv - (a * pt.gray + b);
            let ar = res.abs();
            if ar < inlier_th {
                inliers += 1;
                inlier_sq_sum += (res * res) as f64;
            }
            if ar > cut {
                energy += rho_cut as f64;
                continue;
            }
            let (w, rho) = if ar <= k {
                (1.0, 0.5 * res * res)
            } else {
                (k / ar, k * (ar - 0.5 * k))
            };
            energy += rho as f64;
            // The residual's Jacobian is `-a * J`; the gain is applied once,
            // in `finish`.
            acc.add(&pt.jacobian, res, w);
        }
        let ne = acc.finish(-f64::from(a));
        Some(Eval {
            ne,
            energy,
            visible,
            inliers,
            inlier_sq_sum,
            correlation: correlation(&moments, visible),
            gain: a,
            bias: b,
        })
    }
}

impl Aligner {
    /// Gain and bias mapping keyframe intensities to camera intensities,
    /// from the points sampled in pass 1 (`warped`, NaN = not visible).
    ///
    /// The affine model matches the median and the median absolute
    /// deviation of both sides over the visible points. The keyframe side
    /// changes only through visibility, so it is computed at a level's first
    /// evaluation (`reference` is `None`) and reused for that level's LM
    /// iterations, which move the visible set by a few points at most.
    fn photometric(
        &self,
        points: &[super::KeyPoint],
        model: IlluminationModel,
        reference: &mut Option<(f32, f32)>,
    ) -> (f32, f32) {
        let warped = &self.warped[..points.len()];
        let visible = || points.iter().zip(warped).filter(|(_, wv)| !wv.is_nan());
        match model {
            IlluminationModel::Median => (
                1.0,
                approx_median_of(visible().map(|(pt, &wv)| wv - pt.gray), -256.0, 256.0),
            ),
            IlluminationModel::Affine => {
                let med_cam = approx_median_of(visible().map(|(_, &wv)| wv), 0.0, 256.0);
                let mad_cam =
                    approx_median_of(visible().map(|(_, &wv)| (wv - med_cam).abs()), 0.0, 256.0);
                let (med_ref, mad_ref) = *reference.get_or_insert_with(|| {
                    let med = approx_median_of(visible().map(|(pt, _)| pt.gray), 0.0, 256.0);
                    let mad = approx_median_of(
                        visible().map(|(pt, _)| (pt.gray - med).abs()),
                        0.0,
                        256.0,
                    );
                    (med, mad)
                });
                let gain = if mad_ref > 1e-3 {
                    mad_cam / mad_ref
                } else {
                    1.0
                };
                (gain, med_cam - gain * med_ref)
            }
        }
    }
}

/// Zero-mean normalized cross-correlation from the sums `[x, y, xx, yy, xy]`
/// of `n` pairs; 0 when either side has no variance.
fn correlation(m: &[f64; 5], n: usize) -> f32 {
    let n = n as f64;
    if n < 2.0 {
        return 0.0;
    }
    let cov = m[4] - m[0] * m[1] / n;
    let var_x = m[2] - m[0] * m[0] / n;
    let var_y = m[3] - m[1] * m[1] / n;
    let denom = (var_x * var_y).sqrt();
    if !(denom > 1e-9 * n) {
        return 0.0;
    }
    (cov / denom).clamp(-1.0, 1.0) as f32
}

/// Bins of [`approx_median`]'s histogram.
const MEDIAN_BINS: usize = 1024;

/// The median of `values` from a histogram of [`MEDIAN_BINS`] bins over
/// `lo..hi` (values outside are counted in the end bins), interpolated
/// linearly inside the median's bin: exact to a fraction of a bin width
/// (0.25 gray levels over 0..256), in one pass, without reordering or
/// allocating. Selection (`select_nth_unstable`) cost a fifth of the
/// per-frame time at four medians per LM evaluation. 0 for an empty slice.
#[cfg(test)]
fn approx_median(values: &[f32], lo: f32, hi: f32) -> f32 {
    approx_median_of(values.iter().copied(), lo, hi)
}

/// [`approx_median`] of the values an iterator yields, so that callers can
/// filter and transform on the fly instead of gathering into scratch.
#[inline(always)]
fn approx_median_of(values: impl Iterator<Item = f32>, lo: f32, hi: f32) -> f32 {
    let mut hist = [0u32; MEDIAN_BINS];
    let scale = MEDIAN_BINS as f32 / (hi - lo);
    let mut n = 0u32;
    for v in values {
        // NaN casts to 0; out-of-range values saturate into the end bins.
        let bin = (((v - lo) * scale) as usize).min(MEDIAN_BINS - 1);
        hist[bin] += 1;
        n += 1;
    }
    if n == 0 {
        return 0.0;
    }
    let half = n as f32 * 0.5;
    let mut below = 0u32;
    for (i, &count) in hist.iter().enumerate() {
        if (below + count) as f32 >= half && count > 0 {
            let frac = (half - below as f32) / count as f32;
            return lo + (i as f32 + frac) / scale;
        }
        below += count;
    }
    hi
}

#[cfg(test)]
mod approx_median_tests {
    use super::*;

    #[test]
    fn matches_the_exact_median_within_a_bin() {
        let mut state = 12345u32;
        let values: Vec<f32> = (0..5001)
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 8) as f32 / (1u32 << 24) as f32 * 200.0 + 20.0
            })
            .collect();
        let mut sorted = values.clone();
        sorted.sort_by(f32::total_cmp);
        let exact = sorted[sorted.len() / 2];
        let approx = approx_median(&values, 0.0, 256.0);
        assert!((approx - exact).abs() < 0.25, "{approx} vs {exact}");
        let shifted: Vec<f32> = values.iter().map(|v| v - 128.0).collect();
        let approx = approx_median(&shifted, -256.0, 256.0);
        assert!((approx - (exact - 128.0)).abs() < 0.5, "{approx}");
    }

    #[test]
    fn degenerate_inputs() {
        assert_eq!(approx_median(&[], 0.0, 256.0), 0.0);
        let v = approx_median(&[7.0; 9], 0.0, 256.0);
        assert!((v - 7.0).abs() < 0.25, "{v}");
        // Out-of-range values land in the end bins instead of panicking.
        let v = approx_median(&[-5.0, 300.0, 1000.0], 0.0, 256.0);
        assert!((255.75..=256.0).contains(&v), "{v}");
        assert!(approx_median(&[f32::NAN, 1.0, 2.0], 0.0, 256.0).is_finite());
    }
}
