//! Block-tridiagonal systems with 2×2 blocks: the constraint Jacobian J of a path with fixed endpoints
//! (HSLT, Kaplanyan et al. 2014, appendix Eq. 11). Block LU without pivoting (block Thomas), the offset
//! solve of supplement Fig. 2, the ray-differential blocks and transfer matrix of Fig. 1, and det J.

use glam::{DMat2, DVec2};

/// A pivot block whose smallest singular value is below this fraction of the size of the terms that
/// formed it is treated as singular. 1e-13 is ~500 ulps: pivots this close to cancellation carry no
/// correct digits, while honest systems with condition numbers of 1e10 keep pivots far above it.
pub const RELATIVE_PIVOT_TOLERANCE: f64 = 1e-13;

/// J for the inner vertices x_1..x_n of a path x_0..x_{n+1}, one block row per inner vertex.
/// Row i holds `a[i] = ∂c_i/∂x_{i-1}`, `b[i] = ∂c_i/∂x_i`, `c[i] = ∂c_i/∂x_{i+1}`. `a[0]` and `c[n-1]`
/// couple to the fixed endpoints: they are not part of J, but the transfer matrices need them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlockTridiagonal {
    pub a: Vec<DMat2>,
    pub b: Vec<DMat2>,
    pub c: Vec<DMat2>,
}

/// The factorisation met a pivot block that is singular (or not finite) relative to its inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("block-tridiagonal system is singular at block row {row}")]
pub struct Singular {
    pub row: usize,
}

/// det J as sign and natural log of the magnitude: for long chains of blocks with units of 1/length the
/// plain product overflows or underflows f64 long before it becomes meaningless.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LogDet {
    /// +1 or −1.
    pub sign: f64,
    pub ln_abs: f64,
}

impl LogDet {
    /// The determinant itself; ±inf or ±0 when it does not fit an f64.
    pub fn value(&self) -> f64 {
        self.sign * self.ln_abs.exp()
    }
}

/// J = L U with L unit block-lower-bidiagonal (sub-diagonal `l[i] = a[i] Λ_{i-1}⁻¹`) and U block-upper-
/// bidiagonal (diagonal Λ_i, super-diagonal c[i]).
#[derive(Clone, Debug)]
pub struct BlockLu {
    system: BlockTridiagonal,
    lambda_inv: Vec<DMat2>,
    /// `l[0]` is unused (zero).
    l: Vec<DMat2>,
    log_det: LogDet,
}

/// Frobenius norm, scaled so blocks near the ends of the f64 range neither overflow nor underflow.
fn frobenius(m: DMat2) -> f64 {
    let largest = m.abs().to_cols_array().into_iter().fold(0.0, f64::max);
    if !(largest > 0.0) || !largest.is_finite() {
        return largest;
    }
    let unit = m * (1.0 / largest);
    largest * (unit.x_axis.length_squared() + unit.y_axis.length_squared()).sqrt()
}

/// Determinant as (sign, ln|det|), computed on the block scaled to unit norm so it cannot underflow.
fn log_det_2x2(m: DMat2) -> (f64, f64) {
    let norm = frobenius(m);
    let det = (m * (1.0 / norm)).determinant();
    (det.signum(), det.abs().ln() + 2.0 * norm.ln())
}

/// Inverse of a 2×2 block, or `None` when its smallest singular value is below
/// `RELATIVE_PIVOT_TOLERANCE` times `scale` (the magnitude of whatever it was computed from).
fn relative_inverse(m: DMat2, scale: f64) -> Option<DMat2> {
    let norm = frobenius(m);
    if !(norm > 0.0) || !norm.is_finite() {
        return None;
    }
    // On the unit-norm block, |det| = σ_min σ_max with σ_max ∈ [1/√2, 1], so |det|·‖m‖ is σ_min(m)
    // to within √2, free of the under- and overflow of the raw determinant.
    let unit = m * (1.0 / norm);
    let det = unit.determinant();
    if !(det.abs() * norm > RELATIVE_PIVOT_TOLERANCE * scale.max(norm)) {
        return None;
    }
    let inv = unit.inverse() * (1.0 / norm);
    inv.is_finite().then_some(inv)
}

/// Inverse of a 2×2 block with the same scale-free singularity test as the factorisation, for callers
/// that invert ray-differential blocks D_j into R_j.
pub fn invert_block(m: DMat2) -> Option<DMat2> {
    relative_inverse(m, frobenius(m))
}

impl BlockTridiagonal {
    /// Number of block rows (inner vertices).
    pub fn len(&self) -> usize {
        self.b.len()
    }

    pub fn is_empty(&self) -> bool {
        self.b.is_empty()
    }

    /// J·x, with the endpoint couplings left out.
    pub fn mul_vec(&self, x: &[DVec2]) -> Vec<DVec2> {
        let n = self.len();
        (0..n)
            .map(|i| {
                let mut r = self.b[i] * x[i];
                if i > 0 {
                    r += self.a[i] * x[i - 1];
                }
                if i + 1 < n {
                    r += self.c[i] * x[i + 1];
                }
                r
            })
            .collect()
    }

    /// Block Thomas factorisation (no pivoting: the diagonal blocks of J dominate in all but
    /// degenerate configurations, and those are exactly what the singularity test is there to reject).
    pub fn factor(&self) -> Result<BlockLu, Singular> {
        self.clone().into_factor()
    }

    /// `factor`, keeping this system inside the factorisation rather than a copy of it (for callers
    /// done with J once it is factored, like each Newton iteration of the walk).
    pub fn into_factor(self) -> Result<BlockLu, Singular> {
        let n = self.len();
        assert!(self.a.len() == n && self.c.len() == n, "a, b and c need one block per row");
        let mut lambda_inv = Vec::with_capacity(n);
        let mut l = Vec::with_capacity(n);
        let mut sign = 1.0;
        let mut ln_abs = 0.0;
        for i in 0..n {
            let (lambda, l_i, scale) = if i == 0 {
                (self.b[0], DMat2::ZERO, frobenius(self.b[0]))
            } else {
                let l_i = self.a[i] * lambda_inv[i - 1];
                let update = l_i * self.c[i - 1];
                (self.b[i] - update, l_i, frobenius(self.b[i]).max(frobenius(update)))
            };
            let inv = relative_inverse(lambda, scale).ok_or(Singular { row: i })?;
            let (det_sign, det_ln) = log_det_2x2(lambda);
            sign *= det_sign;
            ln_abs += det_ln;
            lambda_inv.push(inv);
            l.push(l_i);
        }
        Ok(BlockLu { system: self, lambda_inv, l, log_det: LogDet { sign, ln_abs } })
    }
}

impl BlockLu {
    pub fn len(&self) -> usize {
        self.lambda_inv.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lambda_inv.is_empty()
    }

    /// det J = Π det Λ_i (of an empty system: 1).
    pub fn log_det(&self) -> LogDet {
        self.log_det
    }

    /// Solves J x = rhs (supplement Fig. 2: the predictor's vertex offsets for half-vector offsets).
    /// One step of iterative refinement follows the elimination: without pivoting, a small leading
    /// pivot inflates later ones, and the refinement recovers the digits that growth costs.
    pub fn solve(&self, rhs: &[DVec2]) -> Vec<DVec2> {
        let mut x = rhs.to_vec();
        self.solve_in_place(&mut x);
        let mut correction = self.system.mul_vec(&x);
        for (c, r) in correction.iter_mut().zip(rhs) {
            *c = *r - *c;
        }
        self.solve_in_place(&mut correction);
        if correction.iter().all(|c| c.is_finite()) {
            for (xi, ci) in x.iter_mut().zip(&correction) {
                *xi += *ci;
            }
        }
        x
    }

    /// Solves J X = rhs with 2×2 blocks on the right (Fig. 1 feeds an identity at one row).
    pub fn solve_matrix(&self, rhs: &[DMat2]) -> Vec<DMat2> {
        let mut x = rhs.to_vec();
        self.solve_in_place(&mut x);
        x
    }

    /// Overwrites the right-hand side with the solution: forward substitution through L, then back
    /// substitution through U, each row reading only rows already overwritten (no scratch vectors:
    /// the walk solves once per Newton iteration).
    fn solve_in_place<T>(&self, v: &mut [T])
    where
        T: Copy + std::ops::Sub<Output = T>,
        DMat2: std::ops::Mul<T, Output = T>,
    {
        let n = self.len();
        assert_eq!(v.len(), n, "one right-hand-side block per row");
        for i in 1..n {
            v[i] = v[i] - self.l[i] * v[i - 1];
        }
        for i in (0..n).rev() {
            let r = if i + 1 < n { v[i] - self.system.c[i] * v[i + 1] } else { v[i] };
            v[i] = self.lambda_inv[i] * r;
        }
    }

    /// Block row `row` of J⁻¹: entry j is ∂x_row/∂h_j with every other half vector and both endpoints
    /// fixed. For `row = 0` these are the camera-adjacent blocks D_j of Fig. 1. Instead of one matrix
    /// solve per j (O(n²)), one solve with Jᵀ = Uᵀ Lᵀ and the identity at `row` gives the whole row in O(n).
    pub fn inverse_row(&self, row: usize) -> Vec<DMat2> {
        let n = self.len();
        assert!(row < n, "row {row} out of range for {n} rows");
        // Uᵀ W = E_row: Uᵀ is block-lower with diagonal Λ_iᵀ and sub-diagonal c_{i-1}ᵀ.
        let mut w = vec![DMat2::ZERO; n];
        w[row] = self.lambda_inv[row].transpose();
        for i in row + 1..n {
            w[i] = -(self.lambda_inv[i].transpose() * (self.system.c[i - 1].transpose() * w[i - 1]));
        }
        // Lᵀ Z = W: Lᵀ is unit block-upper with super-diagonal l_{i+1}ᵀ.
        let mut z = w;
        for i in (0..n.saturating_sub(1)).rev() {
            z[i] = z[i] - self.l[i + 1].transpose() * z[i + 1];
        }
        // (J⁻¹)_{row,j} = ((J⁻ᵀ)_{j,row})ᵀ.
        z.into_iter().map(|m| m.transpose()).collect()
    }

    /// T = ∂x_1/∂x_{n+1}: how the first inner vertex follows the fixed far endpoint when every half
    /// vector and x_0 stay fixed (Fig. 1, last block; the generalised geometry term uses |det T|).
    pub fn transfer_from_end(&self) -> DMat2 {
        let n = self.len();
        if n == 0 {
            return DMat2::ZERO;
        }
        let mut t = -(self.lambda_inv[n - 1] * self.system.c[n - 1]);
        for i in (0..n - 1).rev() {
            // U_i = Λ_i⁻¹ c_i.
            t = -(self.lambda_inv[i] * (self.system.c[i] * t));
        }
        t
    }

    /// T = ∂x_n/∂x_0: how the last inner vertex follows the fixed start endpoint (for tracing from the
    /// light, where the roles of the two ends swap).
    pub fn transfer_from_start(&self) -> DMat2 {
        let n = self.len();
        if n == 0 {
            return DMat2::ZERO;
        }
        let mut rhs = vec![DMat2::ZERO; n];
        rhs[0] = -self.system.a[0];
        self.solve_matrix(&rhs)[n - 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;
    use nalgebra::{DMatrix, DVector};

    fn random_block(rng: &mut Sampler) -> DMat2 {
        DMat2::from_cols_array(&[0.0; 4].map(|_: f64| 2.0 * rng.next_f64() - 1.0))
    }

    /// A random system whose diagonal blocks lean towards the identity, as J's do away from folds.
    fn random_system(rng: &mut Sampler, n: usize) -> BlockTridiagonal {
        BlockTridiagonal {
            a: (0..n).map(|_| random_block(rng)).collect(),
            b: (0..n).map(|_| random_block(rng) + DMat2::IDENTITY * 2.5).collect(),
            c: (0..n).map(|_| random_block(rng)).collect(),
        }
    }

    fn dense(sys: &BlockTridiagonal) -> DMatrix<f64> {
        let n = sys.len();
        let mut m = DMatrix::zeros(2 * n, 2 * n);
        let mut put = |row: usize, col: usize, blk: DMat2| {
            for r in 0..2 {
                for c in 0..2 {
                    m[(2 * row + r, 2 * col + c)] = blk.col(c)[r];
                }
            }
        };
        for i in 0..n {
            put(i, i, sys.b[i]);
            if i > 0 {
                put(i, i - 1, sys.a[i]);
            }
            if i + 1 < n {
                put(i, i + 1, sys.c[i]);
            }
        }
        m
    }

    fn to_dvector(v: &[DVec2]) -> DVector<f64> {
        DVector::from_iterator(2 * v.len(), v.iter().flat_map(|p| [p.x, p.y]))
    }

    fn condition_number(m: &DMatrix<f64>) -> f64 {
        let sv = m.clone().svd(false, false).singular_values;
        sv.max() / sv.min()
    }

    /// Rescales block rows and columns by powers of ten up to `decades`: κ(J) grows to ~10^(2·decades)
    /// while the problem stays one that block elimination solves to full relative accuracy.
    fn badly_scaled(rng: &mut Sampler, sys: &BlockTridiagonal, decades: f64) -> BlockTridiagonal {
        let n = sys.len();
        let row: Vec<f64> = (0..n).map(|_| 10f64.powf(decades * (2.0 * rng.next_f64() - 1.0))).collect();
        let col: Vec<f64> = (0..n).map(|_| 10f64.powf(decades * (2.0 * rng.next_f64() - 1.0))).collect();
        let col_end = 10f64.powf(decades * (2.0 * rng.next_f64() - 1.0));
        BlockTridiagonal {
            a: (0..n).map(|i| sys.a[i] * row[i] * if i > 0 { col[i - 1] } else { 1.0 }).collect(),
            b: (0..n).map(|i| sys.b[i] * row[i] * col[i]).collect(),
            c: (0..n).map(|i| sys.c[i] * row[i] * if i + 1 < n { col[i + 1] } else { col_end }).collect(),
        }
    }

    /// Replaces the pivot at `row` by one with smallest singular value `delta` times its size, so
    /// κ(J) ≈ 1/delta with no scaling to hide behind.
    fn nearly_singular(
        rng: &mut Sampler,
        sys: &BlockTridiagonal,
        row: usize,
        delta: f64,
    ) -> BlockTridiagonal {
        let mut out = sys.clone();
        let mut lambda = sys.b[0];
        for i in 1..=row {
            lambda = sys.b[i] - sys.a[i] * lambda.inverse() * sys.c[i - 1];
        }
        // Singular values 2 and 2·delta, with random left and right singular vectors.
        let (left, right) = (6.0 * rng.next_f64(), 6.0 * rng.next_f64());
        let (u, v) = (DVec2::from_angle(left), DVec2::from_angle(left).perp());
        let (p, q) = (DVec2::from_angle(right), DVec2::from_angle(right).perp());
        let target = outer(u, p) * 2.0 + outer(v, q) * (2.0 * delta);
        out.b[row] = sys.b[row] - lambda + target;
        out
    }

    fn outer(a: DVec2, b: DVec2) -> DMat2 {
        DMat2::from_cols(a * b.x, a * b.y)
    }

    fn max_rel_diff(a: &DVector<f64>, b: &DVector<f64>) -> f64 {
        (a - b).amax() / b.amax()
    }

    #[test]
    fn solve_and_determinant_match_dense_lu_for_well_conditioned_chains() {
        let mut rng = Sampler::from_seed(1);
        for n in 1..=32 {
            let sys = random_system(&mut rng, n);
            let rhs: Vec<DVec2> = (0..n).map(|_| random_block(&mut rng).x_axis).collect();
            let lu = sys.factor().expect("diagonally leaning system");
            let x = to_dvector(&lu.solve(&rhs));
            let m = dense(&sys);
            let reference = m.clone().lu().solve(&to_dvector(&rhs)).unwrap();
            assert!(max_rel_diff(&x, &reference) < 1e-12, "n={n}");
            let det = m.determinant();
            let ours = lu.log_det();
            assert_eq!(ours.sign, det.signum(), "n={n}");
            assert!((ours.ln_abs - det.abs().ln()).abs() < 1e-12, "n={n}");
        }
    }

    #[test]
    fn badly_scaled_chains_with_condition_numbers_up_to_1e10_solve_to_1e9() {
        let mut rng = Sampler::from_seed(2);
        let mut worst_kappa: f64 = 0.0;
        for n in 1..=32 {
            let base = random_system(&mut rng, n);
            let sys = badly_scaled(&mut rng, &base, 2.5);
            let m = dense(&sys);
            let kappa = condition_number(&m);
            worst_kappa = worst_kappa.max(kappa);
            let rhs: Vec<DVec2> = (0..n).map(|_| random_block(&mut rng).x_axis).collect();
            let lu = sys.factor().expect("scaling must not trip the relative pivot test");
            let x = to_dvector(&lu.solve(&rhs));
            let reference = m.clone().lu().solve(&to_dvector(&rhs)).unwrap();
            // Componentwise: scaling leaves every entry of x with full relative accuracy.
            let worst = (0..2 * n).map(|i| ((x[i] - reference[i]) / reference[i]).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-9, "n={n} kappa={kappa:e} componentwise rel diff {worst:e}");
            let det = m.determinant();
            assert!((lu.log_det().ln_abs - det.abs().ln()).abs() < 1e-9, "n={n}");
            assert_eq!(lu.log_det().sign, det.signum());
        }
        assert!(worst_kappa > 1e9, "the scaled systems should reach κ ~ 1e10, got {worst_kappa:e}");
    }

    #[test]
    fn intrinsically_ill_conditioned_chains_agree_with_dense_lu() {
        let mut rng = Sampler::from_seed(3);
        for n in [1usize, 2, 5, 17, 32] {
            for delta in [1e-4, 1e-7, 1e-10] {
                let base = random_system(&mut rng, n);
                // The last pivot is the Schur complement: (J⁻¹)_{n-1,n-1} = Λ_{n-1}⁻¹, so κ(J) ≳ 1/delta.
                let sys = nearly_singular(&mut rng, &base, n - 1, delta);
                let m = dense(&sys);
                let kappa = condition_number(&m);
                assert!(kappa > 0.01 / delta, "n={n} delta={delta:e} kappa={kappa:e}");
                let lu = sys.factor().expect("κ ≤ 1e10 is solvable");
                // A right-hand side from a known solution, so the forward error has a yardstick.
                let truth: Vec<DVec2> = (0..n).map(|_| random_block(&mut rng).x_axis).collect();
                let rhs = sys.mul_vec(&truth);
                let x = to_dvector(&lu.solve(&rhs));
                let reference = m.clone().lu().solve(&to_dvector(&rhs)).unwrap();
                let truth = to_dvector(&truth);
                let ours_err = max_rel_diff(&x, &truth);
                let dense_err = max_rel_diff(&reference, &truth);
                // Both are backward stable, so both forward errors stay below κ·ε (with slack 100), and
                // ours is within a small factor of partial-pivoting LU's.
                let bound = 100.0 * kappa * f64::EPSILON;
                assert!(ours_err < bound.max(1e-12), "n={n} δ={delta:e}: {ours_err:e} vs bound {bound:e}");
                assert!(ours_err < 1e-9 || ours_err < 30.0 * dense_err, "{ours_err:e} vs {dense_err:e}");
                // Backward error: the answer solves a system within rounding of J.
                let residual = &m * &x - to_dvector(&rhs);
                let backward = residual.amax() / (m.amax() * x.amax());
                assert!(backward < 1e-14, "n={n} δ={delta:e}: backward error {backward:e}");
                let det = m.determinant();
                assert_eq!(lu.log_det().sign, det.signum());
                assert!((lu.log_det().ln_abs - det.abs().ln()).abs() < 1e-6, "n={n} δ={delta:e}");
            }
        }
    }

    #[test]
    fn inverse_rows_and_matrix_solves_match_the_dense_inverse() {
        let mut rng = Sampler::from_seed(4);
        for n in [1usize, 2, 3, 8, 32] {
            let base = random_system(&mut rng, n);
            let sys = badly_scaled(&mut rng, &base, 1.0);
            let lu = sys.factor().unwrap();
            let inv = dense(&sys).try_inverse().unwrap();
            let block = |r: usize, c: usize| {
                DMat2::from_cols(
                    DVec2::new(inv[(2 * r, 2 * c)], inv[(2 * r + 1, 2 * c)]),
                    DVec2::new(inv[(2 * r, 2 * c + 1)], inv[(2 * r + 1, 2 * c + 1)]),
                )
            };
            for row in [0, n / 2, n - 1] {
                for (j, d) in lu.inverse_row(row).iter().enumerate() {
                    let want = block(row, j);
                    assert!(
                        frobenius(*d - want) <= 1e-10 * frobenius(want) + 1e-300,
                        "n={n} row={row} j={j}"
                    );
                }
            }
            // Fig. 1's way: a matrix right-hand side with I at row j.
            let j = n / 2;
            let mut rhs = vec![DMat2::ZERO; n];
            rhs[j] = DMat2::IDENTITY;
            let cols = lu.solve_matrix(&rhs);
            for (i, x) in cols.iter().enumerate() {
                let want = block(i, j);
                assert!(frobenius(*x - want) <= 1e-10 * frobenius(want) + 1e-300, "n={n} i={i}");
            }
        }
    }

    #[test]
    fn transfer_matrices_match_a_dense_solve_with_the_endpoint_column() {
        let mut rng = Sampler::from_seed(5);
        for n in [1usize, 2, 4, 16, 32] {
            let base = random_system(&mut rng, n);
            let sys = badly_scaled(&mut rng, &base, 1.0);
            let lu = sys.factor().unwrap();
            let m = dense(&sys);
            let lu_dense = m.clone().lu();
            // J dX = −C_end dx_end: read the first inner vertex's block of the response to each column.
            let mut t_end = DMat2::ZERO;
            let mut t_start = DMat2::ZERO;
            for col in 0..2 {
                let mut rhs = DVector::zeros(2 * n);
                rhs[2 * n - 2] = -sys.c[n - 1].col(col).x;
                rhs[2 * n - 1] = -sys.c[n - 1].col(col).y;
                let x = lu_dense.solve(&rhs).unwrap();
                *t_end.col_mut(col) = DVec2::new(x[0], x[1]);
                let mut rhs = DVector::zeros(2 * n);
                rhs[0] = -sys.a[0].col(col).x;
                rhs[1] = -sys.a[0].col(col).y;
                let x = lu_dense.solve(&rhs).unwrap();
                *t_start.col_mut(col) = DVec2::new(x[2 * n - 2], x[2 * n - 1]);
            }
            let ours = lu.transfer_from_end();
            assert!(frobenius(ours - t_end) <= 1e-10 * frobenius(t_end), "n={n}: {ours:?} vs {t_end:?}");
            let ours = lu.transfer_from_start();
            assert!(frobenius(ours - t_start) <= 1e-10 * frobenius(t_start), "n={n}");
        }
    }

    #[test]
    fn singular_pivots_are_reported_at_any_scale_and_never_yield_nan() {
        let mut rng = Sampler::from_seed(6);
        for scale in [1e-30, 1.0, 1e30] {
            let base = random_system(&mut rng, 6);
            let scaled = |s: &BlockTridiagonal| BlockTridiagonal {
                a: s.a.iter().map(|m| *m * scale).collect(),
                b: s.b.iter().map(|m| *m * scale).collect(),
                c: s.c.iter().map(|m| *m * scale).collect(),
            };
            // Exactly rank-deficient pivot at row 3 (up to rounding of the elimination).
            let exact = scaled(&nearly_singular(&mut rng, &base, 3, 0.0));
            assert_eq!(exact.factor().unwrap_err(), Singular { row: 3 }, "scale {scale:e}");
            // A well-posed system stays solvable at every scale, with the same relative answer.
            let good = scaled(&base);
            let rhs: Vec<DVec2> = (0..6).map(|i| DVec2::new(i as f64, 1.0) * scale).collect();
            let x = good.factor().expect("scale alone must not make a system singular").solve(&rhs);
            let x1 =
                base.factor().unwrap().solve(&(0..6).map(|i| DVec2::new(i as f64, 1.0)).collect::<Vec<_>>());
            for (p, q) in x.iter().zip(&x1) {
                assert!((*p - *q).length() <= 1e-12 * q.length().max(1.0));
            }
        }
        let zero = BlockTridiagonal { a: vec![DMat2::ZERO], b: vec![DMat2::ZERO], c: vec![DMat2::ZERO] };
        assert_eq!(zero.factor().unwrap_err(), Singular { row: 0 });
        let nan = BlockTridiagonal {
            a: vec![DMat2::ZERO],
            b: vec![DMat2::from_diagonal(DVec2::new(f64::NAN, 1.0))],
            c: vec![DMat2::ZERO],
        };
        assert!(nan.factor().is_err());
        let inf = BlockTridiagonal {
            a: vec![DMat2::ZERO],
            b: vec![DMat2::IDENTITY * f64::INFINITY],
            c: vec![DMat2::ZERO],
        };
        assert!(inf.factor().is_err());
        assert!(invert_block(DMat2::from_cols(DVec2::new(1.0, 2.0), DVec2::new(2.0, 4.0))).is_none());
        assert!(invert_block(DMat2::IDENTITY * 1e-200).is_some());
    }

    #[test]
    fn a_small_leading_pivot_in_a_well_conditioned_system_still_solves_accurately() {
        let mut rng = Sampler::from_seed(7);
        for n in [2usize, 3, 8, 32] {
            for delta in [1e-3, 1e-6, 1e-8] {
                let base = random_system(&mut rng, n);
                // Row 0's pivot is B_0 itself; J stays well-conditioned but elimination grows by 1/delta.
                let sys = nearly_singular(&mut rng, &base, 0, delta);
                let m = dense(&sys);
                let rhs: Vec<DVec2> = (0..n).map(|_| random_block(&mut rng).x_axis).collect();
                let reference = m.clone().lu().solve(&to_dvector(&rhs)).unwrap();
                let x = to_dvector(&sys.factor().unwrap().solve(&rhs));
                let kappa = condition_number(&m);
                assert!(
                    max_rel_diff(&x, &reference) < 1e-9,
                    "n={n} δ={delta:e} κ={kappa:e}: {:e}",
                    max_rel_diff(&x, &reference)
                );
            }
        }
    }

    #[test]
    fn an_empty_chain_has_unit_determinant_and_no_offsets() {
        let lu = BlockTridiagonal::default().factor().unwrap();
        assert_eq!(lu.log_det().value(), 1.0);
        assert!(lu.solve(&[]).is_empty());
    }
}
