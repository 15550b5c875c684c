//! Fixed-size normal equations `H x = -g` for up to 8 parameters (6 pose +
//! gain + bias), accumulated per point and solved by Cholesky, and the
//! tracker's fast 6-DoF accumulator ([`Accumulator6`]). Stack-only: no
//! allocation.

/// Maximum number of parameters.
pub const MAX_DIM: usize = 8;

/// Weighted least-squares accumulator for `n <= 8` parameters.
#[derive(Debug, Clone, Copy)]
pub struct NormalEquations {
    /// Number of active parameters.
    pub n: usize,
    /// Upper triangle of `H = sum w J^T J`, full storage.
    pub h: [[f64; MAX_DIM]; MAX_DIM],
    /// `g = sum w J^T r`.
    pub g: [f64; MAX_DIM],
    /// `sum w r^2`.
    pub weighted_sq_sum: f64,
    /// Number of accumulated residuals.
    pub count: usize,
}

impl NormalEquations {
    /// A zeroed system of dimension `n` (clamped to `MAX_DIM`).
    pub fn new(n: usize) -> Self {
        Self {
            n: n.min(MAX_DIM),
            h: [[0.0; MAX_DIM]; MAX_DIM],
            g: [0.0; MAX_DIM],
            weighted_sq_sum: 0.0,
            count: 0,
        }
    }

    /// Adds one residual `r` with Jacobian row `j[..n]` and weight `w`.
    #[inline]
    pub fn add(&mut self, j: &[f32; MAX_DIM], r: f32, w: f32) {
        let n = self.n;
        let (r, w) = (r as f64, w as f64);
        for a in 0..n {
            let wja = w * j[a] as f64;
            self.g[a] += wja * r;
            let row = &mut self.h[a];
            for b in a..n {
                row[b] += wja * j[b] as f64;
            }
        }
        self.weighted_sq_sum += w * r * r;
        self.count += 1;
    }

    /// Fills the lower triangle from the upper one.
    pub fn symmetrize(&mut self) {
        for a in 0..self.n {
            for b in 0..a {
                self.h[a][b] = self.h[b][a];
            }
        }
    }

    /// Solves `(H + lambda * diag(H)) x = -g` (after [`Self::symmetrize`]).
    /// `None` when the damped matrix is not positive definite.
    pub fn solve(&self, lambda: f64) -> Option<[f64; MAX_DIM]> {
        let n = self.n;
        let mut a = self.h;
        for i in 0..n {
            a[i][i] *= 1.0 + lambda;
        }
        let l = cholesky(&mut a, n)?;
        let mut rhs = [0.0; MAX_DIM];
        for i in 0..n {
            rhs[i] = -self.g[i];
        }
        Some(cholesky_solve(&l, n, rhs))
    }

    /// The inverse of `H` (after [`Self::symmetrize`]), or `None` if singular.
    pub fn inverse(&self) -> Option<[[f64; MAX_DIM]; MAX_DIM]> {
        let n = self.n;
        let mut a = self.h;
        let l = cholesky(&mut a, n)?;
        let mut inv = [[0.0; MAX_DIM]; MAX_DIM];
        for c in 0..n {
            let mut e = [0.0; MAX_DIM];
            e[c] = 1.0;
            let col = cholesky_solve(&l, n, e);
            for r in 0..n {
                inv[r][c] = col[r];
            }
        }
        Some(inv)
    }
}

/// Points summed in `f32` before the block is folded into `f64`.
const BLOCK: u32 = 256;

/// `sum w J^T [J r]` and `sum w r^2` over 6-vector Jacobians, the tracker's
/// per-point inner loop.
///
/// As in DSO's accumulators, points are summed in `f32` over blocks of
/// [`BLOCK`] and each block is folded into `f64`: an 8-wide `f32` row per
/// Jacobian entry (`[J, r, 0]`) is what the compiler vectorizes, and the
/// `f64` fold keeps the sum of tens of thousands of terms accurate. The
/// whole matrix is accumulated (36 products instead of 21) because the
/// full rows vectorize and the triangle does not.
#[derive(Debug, Clone, Copy)]
pub struct Accumulator6 {
    /// Row `a`: `sum w J_a [J_0..J_5, r, 0]` of the current block.
    block: [[f32; 8]; 6],
    block_sq: f32,
    block_count: u32,
    total: [[f64; 8]; 6],
    total_sq: f64,
    count: usize,
}

impl Default for Accumulator6 {
    fn default() -> Self {
        Self {
            block: [[0.0; 8]; 6],
            block_sq: 0.0,
            block_count: 0,
            total: [[0.0; 8]; 6],
            total_sq: 0.0,
            count: 0,
        }
    }
}

impl Accumulator6 {
    /// Adds one residual `r` with Jacobian `j` and weight `w`.
    #[inline(always)]
    pub fn add(&mut self, j: &[f32; 6], r: f32, w: f32) {
        let row = [j[0], j[1], j[2], j[3], j[4], j[5], r, 0.0];
        for (a, acc) in self.block.iter_mut().enumerate() {
            let wja = w * j[a];
            for (s, &v) in acc.iter_mut().zip(&row) {
                *s += wja * v;
            }
        }
        self.block_sq += w * r * r;
        self.block_count += 1;
        if self.block_count == BLOCK {
            self.fold();
        }
    }

    fn fold(&mut self) {
        for (total, block) in self.total.iter_mut().zip(self.block.iter_mut()) {
            for (t, b) in total.iter_mut().zip(block.iter_mut()) {
                *t += f64::from(*b);
                *b = 0.0;
            }
        }
        self.total_sq += f64::from(self.block_sq);
        self.block_sq = 0.0;
        self.count += self.block_count as usize;
        self.block_count = 0;
    }

    /// The normal equations of the residuals `r` with Jacobian rows
    /// `scale * J` (symmetrized): `H = scale^2 sum w J^T J`,
    /// `g = scale sum w J^T r`. The tracker accumulates the keyframe's
    /// Jacobians as they are and applies the photometric gain here, once.
    pub fn finish(mut self, scale: f64) -> NormalEquations {
        self.fold();
        let mut ne = NormalEquations::new(6);
        for a in 0..6 {
            for b in 0..6 {
                // The two halves of a symmetric sum differ only by rounding;
                // their mean is exactly symmetric.
                ne.h[a][b] = 0.5 * (self.total[a][b] + self.total[b][a]) * scale * scale;
            }
            ne.g[a] = self.total[a][6] * scale;
        }
        ne.weighted_sq_sum = self.total_sq;
        ne.count = self.count;
        ne
    }
}

/// In-place Cholesky `A = L L^T`; returns L (lower). `None` if not SPD.
fn cholesky(a: &mut [[f64; MAX_DIM]; MAX_DIM], n: usize) -> Option<[[f64; MAX_DIM]; MAX_DIM]> {
    let mut l = [[0.0; MAX_DIM]; MAX_DIM];
    for i in 0..n {
        for j in 0..=i {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                if !(s > 1e-12 * a[i][i].abs().max(1e-300)) || !s.is_finite() {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    Some(l)
}

fn cholesky_solve(
    l: &[[f64; MAX_DIM]; MAX_DIM],
    n: usize,
    mut b: [f64; MAX_DIM],
) -> [f64; MAX_DIM] {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * b[k];
        }
        b[i] = s / l[i][i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k][i] * b[k];
        }
        b[i] = s / l[i][i];
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_overdetermined_linear_fit() {
        // r_i = (a x_i + b) - y_i with y = 2x - 1: minimum at a = 2, b = -1
        // starting from a = b = 0: r0 = -y, J = [x, 1].
        let mut ne = NormalEquations::new(2);
        for i in 0..20 {
            let x = i as f32 * 0.5;
            let y = 2.0 * x - 1.0;
            let mut j = [0.0; MAX_DIM];
            j[0] = x;
            j[1] = 1.0;
            ne.add(&j, -y, 1.0);
        }
        ne.symmetrize();
        let sol = ne.solve(0.0).expect("SPD");
        assert!(
            (sol[0] - 2.0).abs() < 1e-9 && (sol[1] + 1.0).abs() < 1e-9,
            "{sol:?}"
        );
        let inv = ne.inverse().expect("SPD");
        // H * inv = I
        for r in 0..2 {
            for c in 0..2 {
                let v: f64 = (0..2).map(|k| ne.h[r][k] * inv[k][c]).sum();
                assert!((v - if r == c { 1.0 } else { 0.0 }).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn accumulator_matches_the_f64_normal_equations() {
        let mut state = 99u32;
        let mut next = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
        };
        let mut reference = NormalEquations::new(6);
        let mut acc = Accumulator6::default();
        let scale = -0.8f32;
        // Not a multiple of the block, so the last partial block counts too.
        for _ in 0..1000 {
            let j = [
                next() * 300.0,
                next() * 300.0,
                next() * 900.0,
                next() * 200.0,
                next() * 200.0,
                next() * 50.0,
            ];
            let (r, w) = (next() * 20.0, 0.5 + 0.5 * next().abs());
            let mut scaled = [0.0f32; MAX_DIM];
            for c in 0..6 {
                scaled[c] = scale * j[c];
            }
            reference.add(&scaled, r, w);
            acc.add(&j, r, w);
        }
        reference.symmetrize();
        let fast = acc.finish(f64::from(scale));
        assert_eq!(fast.count, 1000);
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(1.0);
        for a in 0..6 {
            assert!(rel(fast.g[a], reference.g[a]) < 1e-4, "g[{a}]");
            for b in 0..6 {
                let (x, y) = (fast.h[a][b], reference.h[a][b]);
                assert!(rel(x, y) < 1e-4, "h[{a}][{b}] {x} vs {y}");
            }
        }
        assert!(rel(fast.weighted_sq_sum, reference.weighted_sq_sum) < 1e-4);
        let (x, y) = (
            fast.solve(0.0).expect("SPD"),
            reference.solve(0.0).expect("SPD"),
        );
        for c in 0..6 {
            assert!((x[c] - y[c]).abs() < 1e-4 * y[c].abs().max(1e-3), "x[{c}]");
        }
    }

    #[test]
    fn singular_system_is_rejected() {
        let mut ne = NormalEquations::new(2);
        let mut j = [0.0; MAX_DIM];
        j[0] = 1.0;
        j[1] = 1.0;
        ne.add(&j, 1.0, 1.0);
        ne.symmetrize();
        assert!(ne.solve(0.0).is_none());
        assert!(ne.inverse().is_none());
    }
}
