//! Trajectory evaluation: absolute trajectory error (ATE) and relative pose
//! error (RPE) of an estimate against ground truth.
//!
//! Takes two [`Trajectory`]s (`world_from_camera`, both in the map frame)
//! and gives error statistics. Localization against a map is absolute, so the
//! ATE applies **no alignment** (no Umeyama, no scale): the error at a
//! matched pair is `gt_from_est = inverse(world_from_gt) * world_from_est`,
//! whose translation norm is `|t_est - t_gt|` and whose rotation angle is the
//! angle of `R_gt^T R_est`. This matches `evo_ape tum GT EST` (without
//! `--align`) with `-r trans_part` and `-r angle_deg`.
//!
//! **Association.** Each estimate pose is paired with the ground-truth pose
//! nearest in time, if it is within `max_dt_s`. The default,
//! [`DEFAULT_MAX_DT_S`] = 5 ms, suits 50 Hz data (frames 20 ms apart: a
//! tolerance under half the period can never pick the neighbouring frame).
//! For 30 Hz TUM RGB-D sequences the TUM tools' 0.02 s works too.
//!
//! **RPE** over `delta` frames uses the matched pairs `(i, i + delta)` for
//! `i = 0, delta, 2 delta, ...` (`evo_rpe --delta N --delta_unit f`), with
//! error `inverse(gt_i^-1 gt_j) * (est_i^-1 est_j)`.

mod stats;

pub use stats::ErrorStats;

use crate::dataset::Trajectory;
use crate::geometry::Pose;

/// Default association tolerance, seconds (for 50 Hz sequences).
pub const DEFAULT_MAX_DT_S: f64 = 0.005;

/// Errors of an evaluation.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EvalError {
    /// No estimate pose has a ground-truth pose within the tolerance.
    #[error(
        "no estimate timestamp is within {max_dt_s} s of a ground-truth timestamp \
         (estimate {est_first_s}..{est_last_s} s, ground truth {gt_first_s}..{gt_last_s} s)"
    )]
    NoOverlap {
        /// The association tolerance.
        max_dt_s: f64,
        /// First estimate stamp (NaN when empty).
        est_first_s: f64,
        /// Last estimate stamp (NaN when empty).
        est_last_s: f64,
        /// First ground-truth stamp (NaN when empty).
        gt_first_s: f64,
        /// Last ground-truth stamp (NaN when empty).
        gt_last_s: f64,
    },
    /// The RPE delta is zero or not smaller than the number of matched poses.
    #[error("RPE delta of {delta} frames needs at least {} matched poses, found {matched}", delta + 1)]
    BadDelta {
        /// The requested delta in frames.
        delta: usize,
        /// Matched poses available.
        matched: usize,
    },
    /// The tolerance is negative or not finite.
    #[error("association tolerance {0} s is invalid; expected a finite value >= 0")]
    BadTolerance(f64),
}

/// Translation and rotation error statistics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseErrors {
    /// Translation error, meters.
    pub translation_m: ErrorStats,
    /// Rotation error, degrees.
    pub rotation_deg: ErrorStats,
}

impl PoseErrors {
    fn from_errors(errors: impl Iterator<Item = Pose>) -> Option<Self> {
        let (trans, rot): (Vec<f64>, Vec<f64>) = errors
            .map(|e| (e.translation.vector.norm(), e.rotation.angle().to_degrees()))
            .unzip();
        Some(Self {
            translation_m: ErrorStats::from_samples(&trans)?,
            rotation_deg: ErrorStats::from_samples(&rot)?,
        })
    }
}

/// Pairs `(estimate index, ground-truth index)`: each estimate pose with the
/// ground-truth pose nearest in time within `max_dt_s`. Both trajectories
/// are in increasing time order.
pub fn associate(
    ground_truth: &Trajectory,
    estimate: &Trajectory,
    max_dt_s: f64,
) -> Vec<(usize, usize)> {
    let gt = &ground_truth.stamps_s;
    let mut pairs = Vec::with_capacity(estimate.len());
    for (i_est, &t) in estimate.stamps_s.iter().enumerate() {
        let upper = gt.partition_point(|&g| g < t);
        let nearest = [upper.checked_sub(1), Some(upper)]
            .into_iter()
            .flatten()
            .filter_map(|j| gt.get(j).map(|&g| (j, (g - t).abs())))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((j, dt)) = nearest {
            if dt <= max_dt_s {
                pairs.push((i_est, j));
            }
        }
    }
    pairs
}

fn associate_checked(
    gt: &Trajectory,
    est: &Trajectory,
    max_dt_s: f64,
) -> Result<Vec<(usize, usize)>, EvalError> {
    if !(max_dt_s.is_finite() && max_dt_s >= 0.0) {
        return Err(EvalError::BadTolerance(max_dt_s));
    }
    let pairs = associate(gt, est, max_dt_s);
    if pairs.is_empty() {
        let ends = |t: &Trajectory| {
            (
                t.stamps_s.first().copied().unwrap_or(f64::NAN),
                t.stamps_s.last().copied().unwrap_or(f64::NAN),
            )
        };
        let ((est_first_s, est_last_s), (gt_first_s, gt_last_s)) = (ends(est), ends(gt));
        return Err(EvalError::NoOverlap {
            max_dt_s,
            est_first_s,
            est_last_s,
            gt_first_s,
            gt_last_s,
        });
    }
    Ok(pairs)
}

/// Absolute trajectory error without alignment.
pub fn ate(gt: &Trajectory, est: &Trajectory, max_dt_s: f64) -> Result<PoseErrors, EvalError> {
    let pairs = associate_checked(gt, est, max_dt_s)?;
    let errors = pairs
        .iter()
        .map(|&(e, g)| gt.poses[g].inverse() * est.poses[e]);
    PoseErrors::from_errors(errors).ok_or(EvalError::BadDelta {
        delta: 0,
        matched: 0,
    })
}

/// Relative pose error over `delta` matched frames.
pub fn rpe(
    gt: &Trajectory,
    est: &Trajectory,
    max_dt_s: f64,
    delta: usize,
) -> Result<PoseErrors, EvalError> {
    let pairs = associate_checked(gt, est, max_dt_s)?;
    if delta == 0 || delta >= pairs.len() {
        return Err(EvalError::BadDelta {
            delta,
            matched: pairs.len(),
        });
    }
    let errors = pairs
        .iter()
        .step_by(delta)
        .zip(pairs.iter().step_by(delta).skip(1))
        .map(|(&(ei, gi), &(ej, gj))| {
            let gt_rel = gt.poses[gi].inverse() * gt.poses[gj];
            let est_rel = est.poses[ei].inverse() * est.poses[ej];
            gt_rel.inverse() * est_rel
        });
    PoseErrors::from_errors(errors).ok_or(EvalError::BadDelta {
        delta,
        matched: pairs.len(),
    })
}

/// A full evaluation, as `star eval` prints it.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// Poses in the ground truth.
    pub gt_len: usize,
    /// Poses in the estimate.
    pub est_len: usize,
    /// Estimate poses matched to ground truth.
    pub matched: usize,
    /// The association tolerance used, seconds.
    pub max_dt_s: f64,
    /// Absolute trajectory error (no alignment).
    pub ate: PoseErrors,
    /// Relative pose error and its delta in frames, when requested and possible.
    pub rpe: Option<(usize, PoseErrors)>,
}

/// Computes ATE, and RPE over `rpe_delta` frames when given.
pub fn evaluate(
    gt: &Trajectory,
    est: &Trajectory,
    max_dt_s: f64,
    rpe_delta: Option<usize>,
) -> Result<Evaluation, EvalError> {
    let matched = associate_checked(gt, est, max_dt_s)?.len();
    let ate = ate(gt, est, max_dt_s)?;
    let rpe = match rpe_delta {
        Some(delta) => Some((delta, rpe(gt, est, max_dt_s, delta)?)),
        None => None,
    };
    Ok(Evaluation {
        gt_len: gt.len(),
        est_len: est.len(),
        matched,
        max_dt_s,
        ate,
        rpe,
    })
}

impl std::fmt::Display for Evaluation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "matched {} of {} estimate poses to {} ground-truth poses (max dt {} s); no alignment",
            self.matched, self.est_len, self.gt_len, self.max_dt_s
        )?;
        writeln!(
            f,
            "{:<22} {:>6} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
            "metric", "n", "rmse", "mean", "median", "std", "min", "max"
        )?;
        let mut row = |name: &str, s: &ErrorStats| {
            writeln!(
                f,
                "{:<22} {:>6} {:>10.5} {:>10.5} {:>10.5} {:>10.5} {:>10.5} {:>10.5}",
                name, s.count, s.rmse, s.mean, s.median, s.std, s.min, s.max
            )
        };
        row("ATE translation [m]", &self.ate.translation_m)?;
        row("ATE rotation [deg]", &self.ate.rotation_deg)?;
        if let Some((delta, rpe)) = &self.rpe {
            row(&format!("RPE/{delta}f translation [m]"), &rpe.translation_m)?;
            row(&format!("RPE/{delta}f rotation [deg]"), &rpe.rotation_deg)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
