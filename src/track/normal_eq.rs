//! Fixed-size normal equations `H x = -g` for up to 8 parameters (6 pose +
//! gain + bias), accumulated per point and solved by Cholesky. Stack-only:
//! no allocation.

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
