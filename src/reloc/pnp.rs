//! Absolute camera pose from 2D-3D correspondences (PnP) for
//! relocalization: the minimal solver [`p3p`] (Lambda Twist) and
//! [`RansacPnp`], a RANSAC around it that refines the best hypothesis with
//! Levenberg-Marquardt on SE(3).
//!
//! Takes world points (meters) and their observations as normalized,
//! undistorted image coordinates (`x/z, y/z`; camera x right, y down,
//! z forward). Gives `world_from_camera`, the inlier count and mask, and the
//! RMS reprojection error in normalized units (pixels / focal length).
//! After [`RansacPnp::new`] nothing here allocates.
//!
//! **Scoring in `f32` lanes.** Where a frame has no pose to find (a place
//! that is not the camera's, a look-alike room matched without the ratio
//! test) RANSAC draws every one of its hypotheses and scores each against
//! every correspondence: 5 000 hypotheses of up to 4 poses over 300
//! points. Hypotheses are therefore scored ([`ScoreSet`]) on the points
//! centred on their mean and stored in `f32`, one array per coordinate,
//! [`LANES`] at a time, with AVX2 where the CPU has it (the same
//! arithmetic in the same order either way, so the result does not depend
//! on the CPU). A point 20 m from the centre is held to 2 um, against an
//! inlier bound of 3 px (6e-3 in normalized units); only the choice of
//! the best hypothesis reads these figures: its inliers are collected and
//! refined in `f64`, as before.

use nalgebra::{
    Matrix3, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3, Vector6,
};

use crate::geometry::{exp_se3, renormalized, Pose};
use crate::rng::SplitMix64;

/// Points nearer than this in front of the camera (or behind it) are never
/// inliers, meters.
pub const MIN_DEPTH_M: f64 = 0.05;
/// Levenberg-Marquardt iterations per refinement round.
const REFINE_ITERATIONS: usize = 8;
/// Newton steps polishing the P3P depths, at most ...
const DEPTH_NEWTON_STEPS: usize = 5;
/// ... stopping once the squared distances hold to this fraction of the
/// largest (a step then moves a depth by about 1e-12 of itself).
const DEPTH_CONVERGED: f64 = 1e-12;

/// Lambda Twist P3P (Persson & Nordberg, ECCV 2018): the poses
/// `camera_from_world` that put each of the three `world_m` points on its
/// ray `bearings[i]` (any length; normalized here), in front of the camera.
/// Writes up to four into `out` and returns how many. Degenerate input
/// (non-finite or zero bearings, coinciding rays, coincident or collinear
/// points) gives 0; a written pose is always finite.
pub fn p3p(
    world_m: &[Vector3<f64>; 3],
    bearings: &[Vector3<f64>; 3],
    out: &mut [Pose; 4],
) -> usize {
    let mut y = [Vector3::zeros(); 3];
    for (yi, b) in y.iter_mut().zip(bearings) {
        let n = b.norm();
        if !(n > 1e-12 && n.is_finite()) {
            return 0;
        }
        *yi = b / n;
    }
    let [x1, x2, x3] = world_m;
    let (d12, d13, d23) = (x1 - x2, x1 - x3, x2 - x3);
    let (a12, a13, a23) = (d12.norm_squared(), d13.norm_squared(), d23.norm_squared());
    let scale = a12.max(a13).max(a23);
    // Collinear, coincident or non-finite points; coinciding rays.
    if !(d12.cross(&d13).norm_squared() > 1e-10 * scale * scale && scale.is_finite())
        || (0..3).any(|i| !(y[i].cross(&y[(i + 1) % 3]).norm_squared() > 1e-12))
    {
        return 0;
    }
    let (b12, b13, b23) = (y[0].dot(&y[1]), y[0].dot(&y[2]), y[1].dot(&y[2]));
    // |l_i y_i - l_j y_j|^2 = a_ij with the scale eliminated: two
    // homogeneous conics l' D1 l = 0 and l' D2 l = 0 in the depths l.
    #[rustfmt::skip]
    let d1 = Matrix3::new(
        a23, -a23 * b12, 0.0,
        -a23 * b12, a23 - a12, a12 * b23,
        0.0, a12 * b23, -a12,
    );
    #[rustfmt::skip]
    let d2 = Matrix3::new(
        a23, 0.0, -a23 * b13,
        0.0, -a13, a13 * b23,
        -a23 * b13, a13 * b23, a23 - a13,
    );
    // det(D1 + g D2) = c3 g^3 + c2 g^2 + c1 g + c0; any real root makes the
    // pencil degenerate: a pair of planes through the origin.
    let c3 = d2.determinant();
    let c2 = cofactors(&d2).component_mul(&d1).sum() / c3;
    let c1 = cofactors(&d1).component_mul(&d2).sum() / c3;
    let c0 = d1.determinant() / c3;
    let Some(gamma) = cubic_root(c2, c1, c0) else {
        return 0;
    };
    let d0 = d1 + d2 * gamma;
    // Eigen-decomposition of the rank-2 D0: sig1 e1 e1' + sig2 e2 e2'.
    let trace = d0.trace();
    let minors = 0.5 * (trace * trace - d0.norm_squared()); // symmetric D0
    let disc = (0.25 * trace * trace - minors).max(0.0).sqrt();
    let (mut sig1, mut sig2) = (0.5 * trace + disc, 0.5 * trace - disc);
    if sig1.abs() < sig2.abs() {
        std::mem::swap(&mut sig1, &mut sig2);
    }
    let eigenvector = |sig: f64| null_vector(&(d0 - Matrix3::identity() * sig));
    let (Some(e1), Some(e2)) = (eigenvector(sig1), eigenvector(sig2)) else {
        return 0;
    };
    let s = (-sig2 / sig1).max(0.0).sqrt();
    let mut count = 0;
    for sign in [1.0, -1.0] {
        // The plane (e1 - sign s e2) . l = 0: l1 = w0 l2 + w1 l3.
        let n = e1 - e2 * (sign * s);
        let (w0, w1) = (-n.y / n.x, -n.z / n.x);
        // Substituted into a13 |l1 y1 - l2 y2|^2 = a12 |l1 y1 - l3 y3|^2,
        // divided by l2^2: a quadratic in tau = l3 / l2.
        let qa = (a13 - a12) * w1 * w1 + 2.0 * a12 * b13 * w1 - a12;
        let qb = 2.0 * (a13 - a12) * w0 * w1 - 2.0 * a13 * b12 * w1 + 2.0 * a12 * b13 * w0;
        let qc = (a13 - a12) * w0 * w0 - 2.0 * a13 * b12 * w0 + a13;
        let qd = qb * qb - 4.0 * qa * qc;
        if !(qd >= 0.0) {
            continue;
        }
        let q = -0.5 * (qb + qd.sqrt().copysign(qb));
        for tau in [q / qa, qc / q] {
            if !(tau > 0.0) || count == out.len() {
                continue;
            }
            let l2 = (a23 / (tau * tau - 2.0 * b23 * tau + 1.0)).sqrt();
            let mut l = Vector3::new(w0 * l2 + w1 * tau * l2, l2, tau * l2);
            refine_depths(&mut l, [a12, a13, a23], [b12, b13, b23]);
            if !l.iter().all(|&v| v > 0.0) {
                continue;
            }
            let p = [y[0] * l.x, y[1] * l.y, y[2] * l.z];
            let rotation = frame(&(p[0] - p[1]), &(p[0] - p[2])) * frame(&d12, &d13).transpose();
            let t = p[0] - rotation * x1;
            if rotation.iter().chain(t.iter()).all(|v| v.is_finite()) {
                let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
                    rotation,
                ));
                out[count] = Pose::from_parts(Translation3::from(t), q);
                count += 1;
            }
        }
    }
    count
}

/// The cofactor matrix of a symmetric `m` (columns: crosses of the others).
fn cofactors(m: &Matrix3<f64>) -> Matrix3<f64> {
    let c = |i: usize| m.column(i).into_owned();
    Matrix3::from_columns(&[c(1).cross(&c(2)), c(2).cross(&c(0)), c(0).cross(&c(1))])
}

/// A real root of `g^3 + c2 g^2 + c1 g + c0` (the largest of three),
/// Newton-polished; `None` for non-finite coefficients.
fn cubic_root(c2: f64, c1: f64, c0: f64) -> Option<f64> {
    if !(c2.is_finite() && c1.is_finite() && c0.is_finite()) {
        return None;
    }
    // Depressed: g = t - c2 / 3, t^3 + a t + b = 0.
    let a = c1 - c2 * c2 / 3.0;
    let b = 2.0 * c2 * c2 * c2 / 27.0 - c2 * c1 / 3.0 + c0;
    let disc = 0.25 * b * b + a * a * a / 27.0;
    let t = if disc > 0.0 || a >= 0.0 {
        let r = disc.max(0.0).sqrt();
        (-0.5 * b + r).cbrt() + (-0.5 * b - r).cbrt()
    } else {
        let arg = (1.5 * b / a * (-3.0 / a).sqrt()).clamp(-1.0, 1.0);
        2.0 * (-a / 3.0).sqrt() * (arg.acos() / 3.0).cos()
    };
    let mut g = t - c2 / 3.0;
    for _ in 0..2 {
        let f = ((g + c2) * g + c1) * g + c0;
        let df = (3.0 * g + 2.0 * c2) * g + c1;
        if df != 0.0 {
            g -= f / df;
        }
    }
    g.is_finite().then_some(g)
}

/// Unit vector spanning the null space of a rank-2 `m` (the largest cross
/// product of two of its rows), or `None`.
fn null_vector(m: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let r = |i: usize| m.row(i).transpose();
    let crosses = [r(0).cross(&r(1)), r(0).cross(&r(2)), r(1).cross(&r(2))];
    let best = crosses
        .iter()
        .max_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))?;
    let n = best.norm();
    (n > 0.0 && n.is_finite()).then(|| best / n)
}

/// Newton steps on `l_i^2 - 2 b_ij l_i l_j + l_j^2 = a_ij` (pairs 12, 13, 23),
/// until every equation holds to [`DEPTH_CONVERGED`] of the largest `a_ij`.
fn refine_depths(l: &mut Vector3<f64>, a: [f64; 3], b: [f64; 3]) {
    let converged = DEPTH_CONVERGED * a[0].max(a[1]).max(a[2]);
    for _ in 0..DEPTH_NEWTON_STEPS {
        let (l1, l2, l3) = (l.x, l.y, l.z);
        let r = Vector3::new(
            l1 * l1 - 2.0 * b[0] * l1 * l2 + l2 * l2 - a[0],
            l1 * l1 - 2.0 * b[1] * l1 * l3 + l3 * l3 - a[1],
            l2 * l2 - 2.0 * b[2] * l2 * l3 + l3 * l3 - a[2],
        );
        if r.amax() <= converged {
            return;
        }
        #[rustfmt::skip]
        let j = Matrix3::new(
            l1 - b[0] * l2, l2 - b[0] * l1, 0.0,
            l1 - b[1] * l3, 0.0, l3 - b[1] * l1,
            0.0, l2 - b[2] * l3, l3 - b[2] * l2,
        ) * 2.0;
        match j.try_inverse() {
            Some(inv) if r.iter().all(|v| v.is_finite()) => *l -= inv * r,
            _ => return,
        }
    }
}

/// Orthonormal frame (columns) of the plane spanned by `u` and `v`, `u` first.
fn frame(u: &Vector3<f64>, v: &Vector3<f64>) -> Matrix3<f64> {
    let e1 = u.normalize();
    let e3 = u.cross(v).normalize();
    Matrix3::from_columns(&[e1, e3.cross(&e1), e3])
}

/// Settings of [`RansacPnp::solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpParams {
    /// Most RANSAC hypotheses (3-point samples); fewer once `confidence` is
    /// reached for the best inlier ratio so far.
    pub max_iterations: usize,
    /// Largest reprojection error of an inlier, normalized units (pixels /
    /// focal length).
    pub threshold: f64,
    /// Fewest inliers of an accepted pose (at least 4 in any case).
    pub min_inliers: usize,
    /// Wanted probability of having drawn one all-inlier sample.
    pub confidence: f64,
}

impl Default for PnpParams {
    /// 1000 iterations, 4 px at a 500 px focal length, 12 inliers, 0.999.
    fn default() -> Self {
        Self {
            max_iterations: 1000,
            threshold: 4.0 / 500.0,
            min_inliers: 12,
            confidence: 0.999,
        }
    }
}

/// A pose found by [`RansacPnp::solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpResult {
    /// The camera pose: maps camera coordinates to world coordinates.
    pub world_from_camera: Pose,
    /// Correspondences within the threshold of the refined pose.
    pub inliers: usize,
    /// RMS reprojection error over the inliers, normalized units.
    pub rms: f64,
}

/// One finite correspondence of the current call.
#[derive(Debug, Clone, Copy)]
struct Correspondence {
    world_m: Vector3<f64>,
    normalized: Vector2<f64>,
    /// Index in the caller's slices.
    input: usize,
    inlier: bool,
}

impl Correspondence {
    /// Reprojection error under `camera_from_world`; `None` unless the point
    /// is at least [`MIN_DEPTH_M`] in front of the camera.
    fn residual(&self, camera_from_world: &Pose) -> Option<Vector2<f64>> {
        let p = camera_from_world.rotation * self.world_m + camera_from_world.translation.vector;
        (p.z > MIN_DEPTH_M).then(|| p.xy() / p.z - self.normalized)
    }
}

/// Points scored together, one accumulator each ([`ScoreSet::score`]).
const LANES: usize = 8;
/// The cost is compared with the bound after every this many chunks of
/// [`LANES`] points (the sum is monotonic, so when does not change
/// whether; adding up the lanes after every chunk took a third of the
/// scoring).
const BOUND_EVERY: usize = 4;

/// The finite correspondences of one call as [`RansacPnp`] scores its
/// hypotheses: world points less their mean, and the observations, in
/// `f32`, one array per coordinate.
#[derive(Debug, Clone)]
struct ScoreSet {
    /// Mean of the world points, meters.
    centre_m: Vector3<f64>,
    /// World coordinates less `centre_m`, meters.
    x_m: Vec<f32>,
    y_m: Vec<f32>,
    z_m: Vec<f32>,
    /// Normalized observations.
    u: Vec<f32>,
    v: Vec<f32>,
}

impl ScoreSet {
    fn with_capacity(n: usize) -> Self {
        Self {
            centre_m: Vector3::zeros(),
            x_m: Vec::with_capacity(n),
            y_m: Vec::with_capacity(n),
            z_m: Vec::with_capacity(n),
            u: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
        }
    }

    /// Holds `valid` (at most the capacity given; allocates nothing).
    fn fill(&mut self, valid: &[Correspondence]) {
        let sum = valid.iter().fold(Vector3::zeros(), |s, c| s + c.world_m);
        self.centre_m = sum / valid.len().max(1) as f64;
        for a in [
            &mut self.x_m,
            &mut self.y_m,
            &mut self.z_m,
            &mut self.u,
            &mut self.v,
        ] {
            a.clear();
        }
        for c in valid {
            let w = c.world_m - self.centre_m;
            self.x_m.push(w.x as f32);
            self.y_m.push(w.y as f32);
            self.z_m.push(w.z as f32);
            self.u.push(c.normalized.x as f32);
            self.v.push(c.normalized.y as f32);
        }
    }

    /// MSAC cost and inlier count of `camera_from_world` (each point's
    /// squared reprojection error, capped at `th2`; a point less than
    /// [`MIN_DEPTH_M`] in front of the camera costs `th2`), if the cost
    /// stays below `bound`.
    fn score(&self, camera_from_world: &Pose, th2: f64, bound: f64) -> Option<(f64, usize)> {
        let r = camera_from_world.rotation.to_rotation_matrix();
        let m = r.matrix();
        // p = R (w' + c) + t = R w' + (R c + t).
        let t = r * self.centre_m + camera_from_world.translation.vector;
        let rows = [
            [m[(0, 0)], m[(0, 1)], m[(0, 2)], t.x],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)], t.y],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)], t.z],
        ]
        .map(|row| row.map(|v| v as f32));
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2, checked just above.
                return unsafe { score_avx2(self, &rows, th2 as f32, bound) };
            }
        }
        score_lanes(self, &rows, th2 as f32, bound)
    }
}

/// [`score_lanes`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn score_avx2(
    set: &ScoreSet,
    rows: &[[f32; 4]; 3],
    th2: f32,
    bound: f64,
) -> Option<(f64, usize)> {
    score_lanes(set, rows, th2, bound)
}

/// The scoring loop of [`ScoreSet::score`]: [`LANES`] points at a time,
/// one accumulator per lane, then the remainder in the first lanes, so
/// the sum is the same however the loop is compiled.
#[inline(always)]
fn score_lanes(set: &ScoreSet, rows: &[[f32; 4]; 3], th2: f32, bound: f64) -> Option<(f64, usize)> {
    let [r0, r1, r2] = rows;
    let min_depth = MIN_DEPTH_M as f32;
    let error2 = |x: f32, y: f32, z: f32, u: f32, v: f32| -> f32 {
        let px = r0[0] * x + r0[1] * y + r0[2] * z + r0[3];
        let py = r1[0] * x + r1[1] * y + r1[2] * z + r1[3];
        let pz = r2[0] * x + r2[1] * y + r2[2] * z + r2[3];
        let inv_z = 1.0 / pz;
        let (du, dv) = (px * inv_z - u, py * inv_z - v);
        // Behind or too near the camera: the cap.
        if pz > min_depth {
            (du * du + dv * dv).min(th2)
        } else {
            th2
        }
    };
    let n = set.u.len();
    let full = n - n % LANES;
    let mut cost = [0.0f32; LANES];
    let mut count = [0u32; LANES];
    let points = set.x_m[..full]
        .chunks_exact(LANES)
        .zip(set.y_m[..full].chunks_exact(LANES))
        .zip(set.z_m[..full].chunks_exact(LANES))
        .zip(
            set.u[..full]
                .chunks_exact(LANES)
                .zip(set.v[..full].chunks_exact(LANES)),
        );
    for (k, (((x, y), z), (u, v))) in points.enumerate() {
        let (x, y, z, u, v) = (lanes(x), lanes(y), lanes(z), lanes(u), lanes(v));
        for lane in 0..LANES {
            let e2 = error2(x[lane], y[lane], z[lane], u[lane], v[lane]);
            cost[lane] += e2;
            count[lane] += u32::from(e2 < th2);
        }
        if k % BOUND_EVERY == BOUND_EVERY - 1 && f64::from(cost.iter().sum::<f32>()) >= bound {
            return None;
        }
    }
    for (lane, i) in (full..n).enumerate() {
        let e2 = error2(set.x_m[i], set.y_m[i], set.z_m[i], set.u[i], set.v[i]);
        cost[lane] += e2;
        count[lane] += u32::from(e2 < th2);
    }
    let total = f64::from(cost.iter().sum::<f32>());
    (total < bound).then(|| (total, count.iter().sum::<u32>() as usize))
}

/// One chunk of [`LANES`] values as an array (the chunks of
/// [`score_lanes`] are exactly that long).
#[inline(always)]
fn lanes(chunk: &[f32]) -> [f32; LANES] {
    let mut a = [0.0; LANES];
    a.copy_from_slice(chunk);
    a
}

/// RANSAC P3P with MSAC scoring, then Levenberg-Marquardt on the inliers.
/// Every buffer is sized in [`RansacPnp::new`]; [`RansacPnp::solve`]
/// allocates nothing.
#[derive(Debug, Clone)]
pub struct RansacPnp {
    capacity: usize,
    /// The finite correspondences of the last call.
    valid: Vec<Correspondence>,
    /// The same, as hypotheses are scored.
    scored: ScoreSet,
    /// Inlier flags per input of the last call.
    mask: Vec<bool>,
}

impl RansacPnp {
    /// A solver for up to `max_correspondences` correspondences per call.
    pub fn new(max_correspondences: usize) -> Self {
        let n = max_correspondences;
        Self {
            capacity: n,
            valid: Vec::with_capacity(n),
            scored: ScoreSet::with_capacity(n),
            mask: Vec::with_capacity(n),
        }
    }

    /// Most correspondences one call uses.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The camera pose from world points `world_m` and their observations
    /// `normalized` (same order), deterministic for a given `seed`. Only the
    /// first [`Self::capacity`] correspondences are used; those with a
    /// non-finite coordinate are skipped. `None` with fewer than 4
    /// correspondences, mismatched lengths, a threshold that is not
    /// positive, or fewer than `params.min_inliers` inliers.
    pub fn solve(
        &mut self,
        world_m: &[Vector3<f64>],
        normalized: &[Vector2<f64>],
        params: &PnpParams,
        seed: u64,
    ) -> Option<PnpResult> {
        self.mask.clear();
        let th2 = params.threshold * params.threshold;
        if world_m.len() != normalized.len() || world_m.len() < 4 || !(th2 > 0.0 && th2.is_finite())
        {
            return None;
        }
        let used = world_m.len().min(self.capacity);
        self.mask.resize(used, false);
        self.valid.clear();
        for (input, (p, x)) in world_m.iter().zip(normalized).take(used).enumerate() {
            if p.iter().chain(x.iter()).all(|v| v.is_finite()) {
                let c = Correspondence {
                    world_m: *p,
                    normalized: *x,
                    input,
                    inlier: false,
                };
                self.valid.push(c);
            }
        }
        let n = self.valid.len();
        let min_inliers = params.min_inliers.max(4);
        if n < min_inliers {
            return None;
        }
        self.scored.fill(&self.valid);
        let mut rng = SplitMix64::new(seed);
        let mut hypotheses = [Pose::identity(); 4];
        let (mut best, mut best_cost) = (Pose::identity(), f64::INFINITY);
        let (mut iteration, mut needed) = (0, params.max_iterations);
        while iteration < needed {
            iteration += 1;
            // Three distinct indices, uniformly.
            let i0 = rng.below(n);
            let i1 = rng.below(n - 1);
            let i1 = i1 + usize::from(i1 >= i0);
            let (lo, hi) = (i0.min(i1), i0.max(i1));
            let i2 = rng.below(n - 2);
            let i2 = i2 + usize::from(i2 >= lo);
            let i2 = i2 + usize::from(i2 >= hi);
            let [a, b, c] = [i0, i1, i2].map(|i| self.valid[i]);
            let bearings = [a, b, c].map(|c| c.normalized.push(1.0));
            let count = p3p(
                &[a.world_m, b.world_m, c.world_m],
                &bearings,
                &mut hypotheses,
            );
            for h in &hypotheses[..count] {
                if let Some((cost, inliers)) = self.scored.score(h, th2, best_cost) {
                    (best, best_cost) = (*h, cost);
                    needed = needed.min(iterations_needed(inliers, n, params.confidence));
                }
            }
        }
        if !best_cost.is_finite() {
            return None;
        }
        // Refine on the inliers, collect them again, refine once more.
        let mut inliers = self.collect(&best, th2);
        for _ in 0..2 {
            if inliers < 4 {
                return None;
            }
            best = self.refine(best, th2);
            inliers = self.collect(&best, th2);
        }
        if inliers < min_inliers {
            return None;
        }
        let mut sum2 = 0.0;
        for c in self.valid.iter().filter(|c| c.inlier) {
            self.mask[c.input] = true;
            sum2 += c.residual(&best).map_or(0.0, |r| r.norm_squared());
        }
        let rms = (sum2 / inliers as f64).sqrt();
        Some(PnpResult {
            world_from_camera: best.inverse(),
            inliers,
            rms,
        })
    }

    /// Inlier flags of the last [`Self::solve`], one per input used (the
    /// first [`Self::capacity`]); empty or all false after a `None`.
    pub fn inlier_mask(&self) -> &[bool] {
        &self.mask
    }

    /// Marks the inliers of `camera_from_world`; returns their count.
    fn collect(&mut self, camera_from_world: &Pose, th2: f64) -> usize {
        for c in &mut self.valid {
            c.inlier = c
                .residual(camera_from_world)
                .is_some_and(|r| r.norm_squared() < th2);
        }
        self.valid.iter().filter(|c| c.inlier).count()
    }

    /// Sum of squared errors over the inliers; one that left the view costs
    /// `penalty`.
    fn inlier_cost(&self, camera_from_world: &Pose, penalty: f64) -> f64 {
        let inliers = self.valid.iter().filter(|c| c.inlier);
        inliers
            .map(|c| {
                c.residual(camera_from_world)
                    .map_or(penalty, |r| r.norm_squared())
            })
            .sum()
    }

    /// Levenberg-Marquardt on the inliers' reprojection error, stepping by
    /// a left perturbation `exp(xi) * camera_from_world`, `xi = [v; w]`.
    fn refine(&self, mut camera_from_world: Pose, th2: f64) -> Pose {
        let penalty = 100.0 * th2;
        let mut cost = self.inlier_cost(&camera_from_world, penalty);
        let mut damping = 1e-4;
        for _ in 0..REFINE_ITERATIONS {
            let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
            for c in self.valid.iter().filter(|c| c.inlier) {
                let p =
                    camera_from_world.rotation * c.world_m + camera_from_world.translation.vector;
                if !(p.z > MIN_DEPTH_M) {
                    continue;
                }
                let r = p.xy() / p.z - c.normalized;
                // Rows of d(x/z, y/z)/dp; with dp = v + w x p, the w part of
                // a row j is p x j.
                let ju = Vector3::new(1.0 / p.z, 0.0, -p.x / (p.z * p.z));
                let jv = Vector3::new(0.0, 1.0 / p.z, -p.y / (p.z * p.z));
                for (j, e) in [(ju, r.x), (jv, r.y)] {
                    let w = p.cross(&j);
                    let row = Vector6::new(j.x, j.y, j.z, w.x, w.y, w.z);
                    h += row * row.transpose();
                    g += row * e;
                }
            }
            let mut improved = false;
            while damping < 1e6 {
                let mut a = h;
                for i in 0..6 {
                    a[(i, i)] += damping * h[(i, i)].max(1e-12);
                }
                let step = a.cholesky().map(|ch| -ch.solve(&g));
                let candidate = step.map(|xi| exp_se3(&xi) * camera_from_world);
                let candidate_cost =
                    candidate.map_or(f64::INFINITY, |p| self.inlier_cost(&p, penalty));
                if let (Some(p), true) = (candidate, candidate_cost < cost) {
                    improved = cost - candidate_cost > 1e-12 * cost;
                    (camera_from_world, cost) = (p, candidate_cost);
                    damping = (damping * 0.1).max(1e-9);
                    break;
                }
                damping *= 10.0;
            }
            if !improved {
                break;
            }
        }
        renormalized(camera_from_world)
    }
}

/// RANSAC iterations for `confidence` of one all-inlier sample when
/// `inliers` of `n` agree (`usize::MAX`: no bound).
fn iterations_needed(inliers: usize, n: usize, confidence: f64) -> usize {
    if !(confidence > 0.0 && confidence < 1.0 && inliers > 0) {
        return usize::MAX;
    }
    let all_inlier = (inliers as f64 / n as f64).powi(3);
    // Both logarithms are negative; `as` saturates a huge count.
    ((1.0 - confidence).ln() / (-all_inlier).ln_1p()).ceil() as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use std::f64::consts::TAU;

    const F_PX: f64 = 500.0;
    type Scene = (Pose, Vec<Vector3<f64>>, Vec<Vector2<f64>>, Vec<bool>);

    /// `n` correspondences 1-6 m in front of a random `world_from_camera`;
    /// the first `outliers * n` get random observations, the others 1 px
    /// of Gaussian noise.
    fn scene(seed: u64, n: usize, outliers: f64, noise_px: f64) -> Scene {
        let mut rng = SplitMix64::new(seed);
        let mut r = |s: f64| rng.range(-s, s);
        let axis = Vector3::new(r(3.0), r(3.0), r(3.0));
        let t = Vector3::new(r(5.0), r(5.0), r(5.0));
        let world_from_camera = Pose::from_parts(t.into(), UnitQuaternion::from_scaled_axis(axis));
        let (mut world, mut obs, mut truth) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..n {
            let x = Vector2::new(r(0.6), r(0.45));
            let p_camera = Point3::from(x.push(1.0) * (3.5 + r(2.5)));
            world.push((world_from_camera * p_camera).coords);
            // Box-Muller.
            let (u, v) = (1.0 - (0.5 + r(0.5)), 0.5 + r(0.5));
            let g = (-2.0 * u.ln()).sqrt() * noise_px / F_PX;
            let noise = Vector2::new(g * (TAU * v).cos(), g * (TAU * v).sin());
            let outlier = (i as f64) < outliers * n as f64;
            obs.push(if outlier {
                Vector2::new(r(0.6), r(0.45))
            } else {
                x + noise
            });
            truth.push(!outlier);
        }
        (world_from_camera, world, obs, truth)
    }

    /// Position error (m) and rotation error (rad) of `estimate`.
    fn pose_error(estimate: &Pose, truth: &Pose) -> (f64, f64) {
        let t_m = (estimate.translation.vector - truth.translation.vector).norm();
        (t_m, (estimate.inverse() * truth).rotation.angle())
    }

    #[test]
    fn p3p_recovers_random_poses_exactly() {
        let mut out = [Pose::identity(); 4];
        let mut exact = 0;
        for seed in 0..200 {
            let (truth, world, obs, _) = scene(seed, 3, 0.0, 0.0);
            // Bearings of any length.
            let bearings = [0, 1, 2].map(|i| obs[i].push(1.0) * (0.5 + i as f64));
            let count = p3p(&[world[0], world[1], world[2]], &bearings, &mut out);
            assert!(out[..count]
                .iter()
                .all(|p| p.to_homogeneous().iter().all(|v| v.is_finite())));
            exact += usize::from(out[..count].iter().any(|c| {
                let (t_m, r_rad) = pose_error(&c.inverse(), &truth);
                t_m < 1e-6 && r_rad < 1e-6
            }));
        }
        assert!(exact >= 195, "{exact} of 200 exact");
    }

    #[test]
    fn p3p_rejects_degenerate_input() {
        let mut out = [Pose::identity(); 4];
        let w = [
            Vector3::new(0.0, 0.0, 3.0),
            Vector3::new(1.0, 0.0, 3.0),
            Vector3::new(0.0, 1.0, 4.0),
        ];
        assert!(p3p(&w, &w, &mut out) >= 1);
        let (nan, zero, inf) = (
            Vector3::repeat(f64::NAN),
            Vector3::zeros(),
            Vector3::repeat(f64::INFINITY),
        );
        let collinear = [w[0], w[1], Vector3::new(2.0, 0.0, 3.0)];
        for (world, bearings) in [
            (collinear, w),
            ([w[0]; 3], w),
            ([w[0], inf, w[2]], w),
            (w, [w[0], zero, w[2]]),
            (w, [w[0], w[0], w[2]]),
            (w, [w[0], nan, w[2]]),
        ] {
            assert_eq!(
                p3p(&world, &bearings, &mut out),
                0,
                "{world:?} {bearings:?}"
            );
        }
    }

    fn check_recovers(outliers: f64, params: &PnpParams) {
        for seed in 0..5 {
            let (truth, world, obs, inlier_truth) = scene(seed, 200, outliers, 1.0);
            let mut pnp = RansacPnp::new(256);
            let found = pnp.solve(&world, &obs, params, seed).expect("a pose");
            let (t_m, r_rad) = pose_error(&found.world_from_camera, &truth);
            assert!(
                t_m < 0.01 && r_rad < 0.2f64.to_radians(),
                "seed {seed}: {t_m} m, {r_rad} rad"
            );
            let expected = inlier_truth.iter().filter(|&&i| i).count();
            assert!(found.inliers >= expected * 95 / 100 && found.inliers <= expected + 10);
            assert!(found.rms < 2.0 / F_PX, "rms {} px", found.rms * F_PX);
            let mask = pnp.inlier_mask();
            assert_eq!(mask.iter().filter(|&&i| i).count(), found.inliers);
            let agree = mask
                .iter()
                .zip(&inlier_truth)
                .filter(|(a, b)| a == b)
                .count();
            assert!(mask.len() == 200 && agree >= 190, "mask agrees on {agree}");
        }
    }

    #[test]
    fn ransac_half_outliers() {
        check_recovers(0.5, &PnpParams::default());
    }

    #[test]
    fn ransac_seventy_percent_outliers() {
        check_recovers(
            0.7,
            &PnpParams {
                max_iterations: 5000,
                ..PnpParams::default()
            },
        );
    }

    #[test]
    fn ransac_is_deterministic_and_uses_the_first_capacity() {
        let (truth, world, obs, _) = scene(11, 200, 0.3, 1.0);
        let params = PnpParams::default();
        let mut pnp = RansacPnp::new(100);
        let a = pnp.solve(&world, &obs, &params, 3).expect("a pose");
        assert_eq!(pnp.inlier_mask().len(), 100);
        let b = pnp
            .solve(&world[..100], &obs[..100], &params, 3)
            .expect("a pose");
        assert_eq!(a, b);
        assert!(pose_error(&a.world_from_camera, &truth).0 < 0.02);
    }

    #[test]
    fn ransac_rejects_degenerate_input() {
        let params = PnpParams::default();
        let mut pnp = RansacPnp::new(64);
        let (_, world, obs, _) = scene(5, 40, 0.0, 1.0);
        let line: Vec<_> = (0..40)
            .map(|i| Vector3::new(0.1 * i as f64, 0.0, 3.0))
            .collect();
        let nan_world = vec![Vector3::repeat(f64::NAN); 40];
        let nan_obs = vec![Vector2::new(f64::NAN, f64::INFINITY); 40];
        for (w, o) in [
            (&world[..3], &obs[..3]),
            (&world[..], &obs[..39]),
            (&vec![world[0]; 40][..], &obs[..]),
            (&line[..], &obs[..]),
            (&nan_world[..], &obs[..]),
            (&world[..], &nan_obs[..]),
        ] {
            assert!(pnp.solve(w, o, &params, 1).is_none());
            assert!(pnp.inlier_mask().iter().all(|&i| !i));
        }
        let bad = PnpParams {
            threshold: f64::NAN,
            ..PnpParams::default()
        };
        assert!(pnp.solve(&world, &obs, &bad, 1).is_none());
        // A few non-finite correspondences among good ones are skipped.
        let (mut w, mut o) = (world.clone(), obs.clone());
        w[3] = Vector3::repeat(f64::NAN);
        o[7] = Vector2::new(f64::INFINITY, 0.0);
        assert!(pnp.solve(&w, &o, &params, 1).is_some());
        assert!(!pnp.inlier_mask()[3] && !pnp.inlier_mask()[7]);
    }

    /// MSAC cost and inlier count of a hypothesis over `valid`, one point
    /// at a time in `f64` (the scoring before [`ScoreSet`]).
    fn score_f64(valid: &[Correspondence], camera_from_world: &Pose, th2: f64) -> (f64, usize) {
        let (mut cost, mut count) = (0.0, 0);
        for c in valid {
            let e2 = c
                .residual(camera_from_world)
                .map_or(th2, |r| r.norm_squared().min(th2));
            cost += e2;
            count += usize::from(e2 < th2);
        }
        (cost, count)
    }

    #[test]
    fn scoring_in_f32_lanes_agrees_with_f64_point_by_point() {
        let th = 3.0 / F_PX;
        let th2 = th * th;
        let mut set = ScoreSet::with_capacity(300);
        let (mut checked, mut counts_off) = (0, 0);
        // Sizes with and without a remainder past the last full chunk; the
        // scenes 20 m from the origin, as a floor's far rooms are.
        for (seed, n) in [(1u64, 300usize), (2, 299), (3, 13), (4, 7), (5, 64)] {
            let (truth, world, obs, _) = scene(seed, n, 0.4, 1.0);
            let offset = Vector3::new(20.0, -15.0, 1.5);
            let valid: Vec<Correspondence> = world
                .iter()
                .zip(&obs)
                .enumerate()
                .map(|(input, (w, x))| Correspondence {
                    world_m: w + offset,
                    normalized: *x,
                    input,
                    inlier: false,
                })
                .collect();
            set.fill(&valid);
            let camera_from_world =
                (Pose::from_parts(offset.into(), UnitQuaternion::identity()) * truth).inverse();
            let mut rng = SplitMix64::new(seed);
            // The true pose, poses near it, and poses from which some
            // points are behind the camera.
            for k in 0..40 {
                let s = 0.02 * k as f64;
                let xi = Vector6::from_fn(|_, _| rng.range(-s, s));
                let hypothesis = exp_se3(&xi) * camera_from_world;
                let (cost, count) = score_f64(&valid, &hypothesis, th2);
                let (lanes_cost, lanes_count) = set
                    .score(&hypothesis, th2, f64::INFINITY)
                    .expect("no bound");
                assert!(
                    (lanes_cost - cost).abs() <= 1e-4 * cost.max(th2),
                    "seed {seed} k {k}: {lanes_cost} against {cost}"
                );
                // A point within float rounding of the bound may count
                // either way.
                assert!(
                    lanes_count.abs_diff(count) <= 1,
                    "{lanes_count} against {count}"
                );
                counts_off += usize::from(lanes_count != count);
                // The bound: a cost at or over it gives None, under it Some.
                assert!(set.score(&hypothesis, th2, lanes_cost).is_none());
                assert!(set
                    .score(&hypothesis, th2, lanes_cost * 1.001 + 1e-12)
                    .is_some());
                checked += 1;
            }
        }
        // Turned about: every point behind the camera costs the cap.
        let (truth, world, obs, _) = scene(6, 45, 0.0, 0.0);
        let valid: Vec<Correspondence> = world
            .iter()
            .zip(&obs)
            .enumerate()
            .map(|(input, (w, x))| Correspondence {
                world_m: *w,
                normalized: *x,
                input,
                inlier: false,
            })
            .collect();
        set.fill(&valid);
        let about = Pose::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
        );
        let turned = about * truth.inverse();
        let (cost, count) = set.score(&turned, th2, f64::INFINITY).expect("no bound");
        assert_eq!(count, 0);
        assert!((cost - 45.0 * th2).abs() < 1e-3 * th2, "{cost}");
        assert_eq!(
            set.score(&truth.inverse(), th2, f64::INFINITY).map(|s| s.1),
            Some(45)
        );
        assert_eq!(checked, 200);
        assert!(counts_off <= 4, "{counts_off} counts differ");
    }
}
