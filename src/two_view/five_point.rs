//! Minimal five-point solver for the essential matrix, after
//! D. Nistér, "An efficient solution to the five-point relative pose
//! problem", PAMI 26(6), 2004.
//!
//! Convention: `q2ᵀ E q1 = 0` for the same point seen as `q1` in view 1 and
//! `q2` in view 2, `E = [t]ₓ R` with `x_2 = R x_1 + t`. The inputs are
//! homogeneous normalised image coordinates (`K⁻¹ [u v 1]ᵀ`) or bearing
//! vectors: any non-zero multiple of the ray works.
//!
//! Steps (Nistér section 3):
//! 1. the five epipolar constraints are five linear equations on the nine
//!    entries of E; their four-dimensional null space gives
//!    `E = x X + y Y + z Z + W` (eq. 7-8);
//! 2. `det E = 0` and `2 E Eᵀ E − tr(E Eᵀ) E = 0` (eq. 3-4) are ten cubics
//!    in x, y, z with twenty monomials;
//! 3. Gauss-Jordan elimination on the first ten monomials, then the rows
//!    `<e> − z<f>`, `<g> − z<h>`, `<i> − z<j>` form a 3×3 matrix `B(z)`
//!    with `B(z) [x y 1]ᵀ = 0` (eq. 11-13);
//! 4. `det B(z)` is of degree ten; each real root z gives `(x, y)` as the
//!    null vector of `B(z)`, hence one E.

use nalgebra::{Matrix3, Vector3};

use super::polynomial::{self, Coefficients, MAX_DEGREE};

/// Up to ten essential matrices, each of unit Frobenius norm.
#[derive(Debug, Clone, Copy)]
pub struct EssentialSolutions {
    matrices: [Matrix3<f64>; 10],
    len: usize,
}

impl EssentialSolutions {
    /// The solutions found (0 to 10).
    pub fn as_slice(&self) -> &[Matrix3<f64>] {
        &self.matrices[..self.len]
    }

    /// Whether no solution was found.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn empty() -> Self {
        Self {
            matrices: [Matrix3::zeros(); 10],
            len: 0,
        }
    }
}

// Monomials in (x, y, z) as exponent triples. The cubic order is Nistér's:
// the first ten are eliminated, the last ten stay.
const LINEAR: [[u8; 3]; 4] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0]];
const QUADRATIC: [[u8; 3]; 10] = [
    [2, 0, 0],
    [0, 2, 0],
    [0, 0, 2],
    [1, 1, 0],
    [1, 0, 1],
    [0, 1, 1],
    [1, 0, 0],
    [0, 1, 0],
    [0, 0, 1],
    [0, 0, 0],
];
const CUBIC: [[u8; 3]; 20] = [
    [3, 0, 0], // x³
    [0, 3, 0], // y³
    [2, 1, 0], // x²y
    [1, 2, 0], // xy²
    [2, 0, 1], // x²z   row <e>
    [2, 0, 0], // x²    row <f>
    [0, 2, 1], // y²z   row <g>
    [0, 2, 0], // y²    row <h>
    [1, 1, 1], // xyz   row <i>
    [1, 1, 0], // xy    row <j>
    [1, 0, 2], // xz²
    [1, 0, 1], // xz
    [1, 0, 0], // x
    [0, 1, 2], // yz²
    [0, 1, 1], // yz
    [0, 1, 0], // y
    [0, 0, 3], // z³
    [0, 0, 2], // z²
    [0, 0, 1], // z
    [0, 0, 0], // 1
];

const fn index_of<const N: usize>(list: &[[u8; 3]; N], e: [u8; 3]) -> usize {
    let mut i = 0;
    while i < N {
        if list[i][0] == e[0] && list[i][1] == e[1] && list[i][2] == e[2] {
            return i;
        }
        i += 1;
    }
    panic!("monomial missing from the list");
}

const fn add(a: [u8; 3], b: [u8; 3]) -> [u8; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Where the product of two linear monomials lands among the quadratics.
const LINEAR_TIMES_LINEAR: [[usize; 4]; 4] = {
    let mut t = [[0; 4]; 4];
    let mut i = 0;
    while i < 4 {
        let mut j = 0;
        while j < 4 {
            t[i][j] = index_of(&QUADRATIC, add(LINEAR[i], LINEAR[j]));
            j += 1;
        }
        i += 1;
    }
    t
};

/// Where a quadratic times a linear monomial lands among the cubics.
const QUADRATIC_TIMES_LINEAR: [[usize; 4]; 10] = {
    let mut t = [[0; 4]; 10];
    let mut i = 0;
    while i < 10 {
        let mut j = 0;
        while j < 4 {
            t[i][j] = index_of(&CUBIC, add(QUADRATIC[i], LINEAR[j]));
            j += 1;
        }
        i += 1;
    }
    t
};

type Linear = [f64; 4];
type Quadratic = [f64; 10];
type Cubic = [f64; 20];

fn mul_ll(a: &Linear, b: &Linear) -> Quadratic {
    let mut out = [0.0; 10];
    for i in 0..4 {
        for j in 0..4 {
            out[LINEAR_TIMES_LINEAR[i][j]] += a[i] * b[j];
        }
    }
    out
}

fn mul_ql(a: &Quadratic, b: &Linear) -> Cubic {
    let mut out = [0.0; 20];
    for i in 0..10 {
        for j in 0..4 {
            out[QUADRATIC_TIMES_LINEAR[i][j]] += a[i] * b[j];
        }
    }
    out
}

fn axpy<const N: usize>(alpha: f64, x: &[f64; N], y: &mut [f64; N]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// Four vectors spanning the null space of the 5×9 constraint matrix, by
/// Gauss-Jordan elimination with full pivoting, then orthonormalised.
/// `None` when the five constraints are not independent.
#[allow(clippy::needless_range_loop)] // index arithmetic over a pivoted matrix
fn null_space(q1: &[Vector3<f64>; 5], q2: &[Vector3<f64>; 5]) -> Option<[[f64; 9]; 4]> {
    let mut a = [[0.0; 9]; 5];
    for (row, (p1, p2)) in a.iter_mut().zip(q1.iter().zip(q2)) {
        let p1 = p1.normalize();
        let p2 = p2.normalize();
        for r in 0..3 {
            for c in 0..3 {
                row[3 * r + c] = p2[r] * p1[c];
            }
        }
    }
    let mut columns = [0, 1, 2, 3, 4, 5, 6, 7, 8];
    for k in 0..5 {
        let (mut best, mut pr, mut pc) = (0.0, k, k);
        for (r, row) in a.iter().enumerate().skip(k) {
            for c in k..9 {
                if row[c].abs() > best {
                    (best, pr, pc) = (row[c].abs(), r, c);
                }
            }
        }
        if best < 1e-12 {
            return None;
        }
        a.swap(k, pr);
        if pc != k {
            for row in a.iter_mut() {
                row.swap(k, pc);
            }
            columns.swap(k, pc);
        }
        let inv = 1.0 / a[k][k];
        for v in a[k].iter_mut() {
            *v *= inv;
        }
        let pivot_row = a[k];
        for (r, row) in a.iter_mut().enumerate() {
            if r != k && row[k] != 0.0 {
                let f = row[k];
                for c in 0..9 {
                    row[c] -= f * pivot_row[c];
                }
            }
        }
    }
    let mut basis = [[0.0; 9]; 4];
    for (j, v) in basis.iter_mut().enumerate() {
        v[columns[5 + j]] = 1.0;
        for i in 0..5 {
            v[columns[i]] = -a[i][5 + j];
        }
    }
    // Modified Gram-Schmidt: a well-conditioned basis keeps the cubic
    // coefficients balanced.
    for j in 0..4 {
        for i in 0..j {
            let d: f64 = (0..9).map(|k| basis[i][k] * basis[j][k]).sum();
            let bi = basis[i];
            axpy(-d, &bi, &mut basis[j]);
        }
        let n = basis[j].iter().map(|v| v * v).sum::<f64>().sqrt();
        for v in basis[j].iter_mut() {
            *v /= n;
        }
    }
    Some(basis)
}

/// The ten cubic constraints (Nistér eq. 3-4) on `E = xX + yY + zZ + W`,
/// one row per equation over the [`CUBIC`] monomials.
#[allow(clippy::needless_range_loop)] // entries of E, E Eᵀ by (row, column)
fn constraint_matrix(basis: &[[f64; 9]; 4]) -> [Cubic; 10] {
    // e[r][c] is entry (r, c) of E as a linear polynomial in x, y, z, 1.
    let mut e = [[[0.0; 4]; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            for (k, b) in basis.iter().enumerate() {
                e[r][c][k] = b[3 * r + c];
            }
        }
    }
    let mut rows = [[0.0; 20]; 10];

    // det E by the first row's cofactors.
    let sub = |a: Quadratic, b: Quadratic| -> Quadratic {
        let mut o = a;
        axpy(-1.0, &b, &mut o);
        o
    };
    let c0 = sub(mul_ll(&e[1][1], &e[2][2]), mul_ll(&e[1][2], &e[2][1]));
    let c1 = sub(mul_ll(&e[1][2], &e[2][0]), mul_ll(&e[1][0], &e[2][2]));
    let c2 = sub(mul_ll(&e[1][0], &e[2][1]), mul_ll(&e[1][1], &e[2][0]));
    axpy(1.0, &mul_ql(&c0, &e[0][0]), &mut rows[0]);
    axpy(1.0, &mul_ql(&c1, &e[0][1]), &mut rows[0]);
    axpy(1.0, &mul_ql(&c2, &e[0][2]), &mut rows[0]);

    // E Eᵀ (symmetric) and its trace.
    let mut eet = [[[0.0; 10]; 3]; 3];
    for i in 0..3 {
        for j in i..3 {
            let mut s = [0.0; 10];
            for k in 0..3 {
                axpy(1.0, &mul_ll(&e[i][k], &e[j][k]), &mut s);
            }
            eet[i][j] = s;
            eet[j][i] = s;
        }
    }
    let mut trace = eet[0][0];
    axpy(1.0, &eet[1][1], &mut trace);
    axpy(1.0, &eet[2][2], &mut trace);

    // 2 E Eᵀ E − tr(E Eᵀ) E, entry by entry.
    for i in 0..3 {
        for j in 0..3 {
            let row = &mut rows[1 + 3 * i + j];
            for k in 0..3 {
                axpy(2.0, &mul_ql(&eet[i][k], &e[k][j]), row);
            }
            axpy(-1.0, &mul_ql(&trace, &e[i][j]), row);
        }
    }
    rows
}

/// Gauss-Jordan on the first ten columns with partial pivoting. `false`
/// when the leading 10×10 block is singular (degenerate configuration).
fn eliminate(m: &mut [Cubic; 10]) -> bool {
    let scale = m
        .iter()
        .flat_map(|r| r.iter())
        .fold(0.0_f64, |s, v| s.max(v.abs()));
    for k in 0..10 {
        let pr = (k..10)
            .max_by(|&a, &b| m[a][k].abs().total_cmp(&m[b][k].abs()))
            .expect("the range k..10 is non-empty");
        if m[pr][k].abs() <= 1e-13 * scale {
            return false;
        }
        m.swap(k, pr);
        let inv = 1.0 / m[k][k];
        for v in m[k].iter_mut() {
            *v *= inv;
        }
        let pivot_row = m[k];
        for (r, row) in m.iter_mut().enumerate() {
            if r != k && row[k] != 0.0 {
                let f = row[k];
                for c in k..20 {
                    row[c] -= f * pivot_row[c];
                }
            }
        }
    }
    true
}

/// One row of `B(z)` from the reduced rows `top` (leading `·z`) and
/// `bottom`: `top − z·bottom` split into its x, y and 1 coefficients, each
/// a polynomial in z (lowest power first).
fn b_row(top: &Cubic, bottom: &Cubic) -> ([f64; 4], [f64; 4], [f64; 5]) {
    let x = [
        top[12],
        top[11] - bottom[12],
        top[10] - bottom[11],
        -bottom[10],
    ];
    let y = [
        top[15],
        top[14] - bottom[15],
        top[13] - bottom[14],
        -bottom[13],
    ];
    let one = [
        top[19],
        top[18] - bottom[19],
        top[17] - bottom[18],
        top[16] - bottom[17],
        -bottom[16],
    ];
    (x, y, one)
}

/// The ten essential constraints (Nistér eq. 3-4) at `E`: `det E` and the
/// nine entries of `2 E Eᵀ E − tr(E Eᵀ) E`.
fn essential_residual(e: &Matrix3<f64>) -> nalgebra::SVector<f64, 10> {
    let eet = e * e.transpose();
    let cubic = 2.0 * eet * e - eet.trace() * e;
    let mut r = nalgebra::SVector::<f64, 10>::zeros();
    r[0] = e.determinant();
    for i in 0..9 {
        r[1 + i] = cubic[(i / 3, i % 3)];
    }
    r
}

/// Gauss-Newton on the ten constraints over the unit sphere of null-space
/// coefficients `c` (`E = Σ c_k B_k`, orthonormal `B_k`, so `‖E‖ = 1`):
/// the elimination and the root isolation leave errors that grow with the
/// size of (x, y, z), which this removes. A step is kept only when it
/// lowers the residual. A poor root may converge onto another solution;
/// the caller drops duplicates.
fn polish_essential(basis: &[Matrix3<f64>; 4], c0: nalgebra::Vector4<f64>) -> Matrix3<f64> {
    let assemble = |c: &nalgebra::Vector4<f64>| -> Matrix3<f64> {
        basis[0] * c[0] + basis[1] * c[1] + basis[2] * c[2] + basis[3] * c[3]
    };
    let mut c = c0.normalize();
    let mut e = assemble(&c);
    let mut r = essential_residual(&e);
    for _ in 0..POLISH_ITERATIONS {
        if r.amax() < POLISHED_RESIDUAL {
            break;
        }
        // Directional derivatives along each basis matrix H:
        // d det = tr(adj(E) H), d(2EEᵀE − tr(EEᵀ)E) =
        // 2(H Eᵀ E + E Hᵀ E + E Eᵀ H) − 2 tr(H Eᵀ) E − tr(E Eᵀ) H.
        let adjugate_t = {
            let mut a = Matrix3::zeros();
            for i in 0..3 {
                for j in 0..3 {
                    let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
                    let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
                    a[(i, j)] = e[(i1, j1)] * e[(i2, j2)] - e[(i1, j2)] * e[(i2, j1)];
                }
            }
            a
        };
        let eet = e * e.transpose();
        let mut j = nalgebra::SMatrix::<f64, 10, 4>::zeros();
        for (k, h) in basis.iter().enumerate() {
            j[(0, k)] = adjugate_t.dot(h);
            let d = 2.0 * (h * e.transpose() * e + e * h.transpose() * e + eet * h)
                - 2.0 * h.dot(&e) * e
                - eet.trace() * h;
            for i in 0..9 {
                j[(1 + i, k)] = d[(i / 3, i % 3)];
            }
        }
        // Tangent step: the normal row c·δ = 0 fixes the free scale.
        let normal = j.transpose() * j + c * c.transpose();
        let Some(step) = normal.try_inverse().map(|inv| inv * (j.transpose() * r)) else {
            break;
        };
        let c_next = (c - step).normalize();
        let e_next = assemble(&c_next);
        let r_next = essential_residual(&e_next);
        // Also stops on NaN.
        if r_next.norm_squared().partial_cmp(&r.norm_squared()) != Some(std::cmp::Ordering::Less) {
            break;
        }
        (c, e, r) = (c_next, e_next, r_next);
    }
    e
}

const POLISH_ITERATIONS: usize = 10;

/// Residual of an unpolished root above which det B(z) is deemed
/// ill-conditioned for the current parameterisation.
const ILL_CONDITIONED_RESIDUAL: f64 = 1e-6;

/// Residual below which a solution is not polished further.
const POLISHED_RESIDUAL: f64 = 1e-14;

/// Largest residual of the essential constraints (Nistér eq. 3-4, for
/// unit-norm E) a returned solution may have.
const MAX_CONSTRAINT_RESIDUAL: f64 = 1e-9;

/// All real essential matrices through five correspondences (at most
/// ten). Empty when the five are degenerate (repeated points, fewer than
/// five independent constraints) or a coordinate is not finite.
pub fn five_point(q1: &[Vector3<f64>; 5], q2: &[Vector3<f64>; 5]) -> EssentialSolutions {
    let mut out = EssentialSolutions::empty();
    if q1
        .iter()
        .chain(q2)
        .any(|q| !q.iter().all(|v| v.is_finite()) || q.norm() == 0.0)
    {
        return out;
    }
    let Some(basis) = null_space(q1, q2) else {
        return out;
    };
    // When det B(z) is ill-conditioned for this parameterisation (its
    // roots cluster and lose accuracy), solve again with the roles of the
    // null-space vectors rotated, so that another ratio plays z.
    for shift in 0..4 {
        let rotated = std::array::from_fn(|k| basis[(k + shift) % 4]);
        if solve_with_basis(&rotated, &mut out) {
            break;
        }
    }
    out
}

/// Adds the solutions found with `E = xX + yY + zZ + W` for the given
/// basis to `out`; `false` when a real root of det B(z) was too inaccurate
/// to polish (the caller then tries another parameterisation).
fn solve_with_basis(basis: &[[f64; 9]; 4], out: &mut EssentialSolutions) -> bool {
    let basis_matrices = basis.map(|b| Matrix3::from_row_slice(&b));
    let mut m = constraint_matrix(basis);
    if !eliminate(&mut m) {
        return false;
    }
    let rows = [
        b_row(&m[4], &m[5]),
        b_row(&m[6], &m[7]),
        b_row(&m[8], &m[9]),
    ];

    // det B(z) by the cofactors of the x column.
    let mut det: Coefficients = [0.0; MAX_DEGREE + 1];
    let mut minor = [0.0; 8];
    let mut term = [0.0; 11];
    let cofactor = |a: usize, b: usize, minor: &mut [f64; 8]| {
        // y_a * one_b − one_a * y_b, degree 7.
        let mut p = [0.0; 8];
        let mut q = [0.0; 8];
        polynomial::multiply(&rows[a].1, 3, &rows[b].2, 4, &mut p);
        polynomial::multiply(&rows[a].2, 4, &rows[b].1, 3, &mut q);
        for i in 0..8 {
            minor[i] = p[i] - q[i];
        }
    };
    for (sign, r, a, b) in [(1.0, 0, 1, 2), (-1.0, 1, 0, 2), (1.0, 2, 0, 1)] {
        cofactor(a, b, &mut minor);
        polynomial::multiply(&rows[r].0, 3, &minor, 7, &mut term);
        axpy(sign, &term, &mut det);
    }

    let mut well_conditioned = true;
    for &z in polynomial::real_roots(&det).as_slice() {
        let eval = |p: &[f64]| polynomial::evaluate(p, p.len() - 1, z);
        let b: [Vector3<f64>; 3] =
            rows.map(|(x, y, one)| Vector3::new(eval(&x), eval(&y), eval(&one)));
        // The null vector of B(z) is the cross product of two of its rows;
        // take the pair whose product is best conditioned in its last entry.
        let candidates = [b[0].cross(&b[1]), b[0].cross(&b[2]), b[1].cross(&b[2])];
        let v = candidates
            .iter()
            .max_by(|a, b| a.z.abs().total_cmp(&b.z.abs()))
            .expect("three candidates");
        let c = nalgebra::Vector4::new(v.x / v.z, v.y / v.z, z, 1.0);
        if !c.iter().all(|x| x.is_finite()) {
            well_conditioned = false;
            continue;
        }
        let start = (basis_matrices[0] * c[0]
            + basis_matrices[1] * c[1]
            + basis_matrices[2] * c[2]
            + basis_matrices[3] * c[3])
            .normalize();
        if essential_residual(&start).amax() > ILL_CONDITIONED_RESIDUAL {
            well_conditioned = false;
        }
        let e = polish_essential(&basis_matrices, c);
        // A root of det B(z) that lost its accuracy gives a matrix off the
        // essential variety: not a solution.
        let off_variety = essential_residual(&e).amax();
        let duplicate = out
            .as_slice()
            .iter()
            .any(|f| (f - e).amax().min((f + e).amax()) < 1e-9);
        if off_variety < MAX_CONSTRAINT_RESIDUAL && !duplicate && out.len < 10 {
            out.matrices[out.len] = e;
            out.len += 1;
        }
    }
    well_conditioned
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::test_scenes::{random_pose, random_scene, skew};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// Largest epipolar residual over the five, and how far E is from
    /// satisfying the essential constraints (both for unit-norm E).
    fn residuals(e: &Matrix3<f64>, q1: &[Vector3<f64>; 5], q2: &[Vector3<f64>; 5]) -> (f64, f64) {
        let epipolar = q1
            .iter()
            .zip(q2)
            .map(|(a, b)| (b.normalize().transpose() * e * a.normalize())[0].abs())
            .fold(0.0, f64::max);
        let trace = (e * e.transpose()).trace();
        let cubic = 2.0 * e * e.transpose() * e - trace * e;
        let essential = cubic.abs().max().max(e.determinant().abs());
        (epipolar, essential)
    }

    #[test]
    fn exact_data_every_solution_fits_and_the_true_one_is_among_them() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // 500 random configurations; about one in a thousand (measured over
        // 2000) has all four parameterisations ill-conditioned and yields no
        // solution, which RANSAC absorbs as a wasted sample.
        for trial in 0..500 {
            let (r, t) = random_pose(&mut rng, 0.5, 1.0);
            let scene = random_scene(&mut rng, &r, &t, 5, 0.0);
            let q1: [Vector3<f64>; 5] = std::array::from_fn(|i| scene.q1[i]);
            let q2: [Vector3<f64>; 5] = std::array::from_fn(|i| scene.q2[i]);
            let solutions = five_point(&q1, &q2);
            assert!(!solutions.is_empty(), "trial {trial}: no solution");
            let truth = (skew(&t) * r).normalize();
            let mut best = f64::INFINITY;
            for e in solutions.as_slice() {
                let (epipolar, essential) = residuals(e, &q1, &q2);
                assert!(
                    epipolar < 1e-9,
                    "trial {trial}: epipolar residual {epipolar:e}"
                );
                assert!(
                    essential < 1e-9,
                    "trial {trial}: essential residual {essential:e}"
                );
                best = best.min((e - truth).norm().min((e + truth).norm()));
            }
            assert!(
                best < 1e-7,
                "trial {trial}: true E not found (closest {best:e})"
            );
        }
    }

    #[test]
    fn degenerate_samples_give_no_solution() {
        let p = Vector3::new(0.1, -0.2, 1.0);
        let same = [p; 5];
        assert!(five_point(&same, &same).is_empty());
        let mut nan = same;
        nan[2].x = f64::NAN;
        assert!(five_point(&nan, &same).is_empty());
    }
}
