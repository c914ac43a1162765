//! Cholesky factorisation of a symmetric positive definite band matrix
//! (Golub and Van Loan, "Matrix Computations", 4th ed., alg. 4.3.5): the
//! normal equations of a B-spline fit are banded, so a trajectory of
//! thousands of control points solves in O(n w^2).

/// Lower band of a symmetric matrix: entry (i, i - d) for d in 0..=w.
#[derive(Debug, Clone)]
pub struct BandMatrix {
    pub n: usize,
    pub half_bandwidth: usize,
    band: Vec<f64>,
}

impl BandMatrix {
    pub fn zeros(n: usize, half_bandwidth: usize) -> Self {
        Self {
            n,
            half_bandwidth,
            band: vec![0.0; n * (half_bandwidth + 1)],
        }
    }

    #[inline]
    fn index(&self, i: usize, j: usize) -> usize {
        debug_assert!(j <= i && i - j <= self.half_bandwidth);
        i * (self.half_bandwidth + 1) + (i - j)
    }

    /// Adds `value` at (i, j) and, by symmetry, (j, i); panics outside the band.
    #[inline]
    pub fn add(&mut self, i: usize, j: usize, value: f64) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        assert!(
            i - j <= self.half_bandwidth,
            "({i}, {j}) is outside the band"
        );
        let k = self.index(i, j);
        self.band[k] += value;
    }

    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        if i - j > self.half_bandwidth {
            0.0
        } else {
            self.band[self.index(i, j)]
        }
    }

    /// In-place `L` with `A = L L^T`; `None` if not positive definite.
    pub fn cholesky(mut self) -> Option<BandCholesky> {
        let w = self.half_bandwidth;
        for i in 0..self.n {
            for j in i.saturating_sub(w)..=i {
                let mut s = self.band[self.index(i, j)];
                for k in i.saturating_sub(w).max(j.saturating_sub(w))..j {
                    s -= self.band[self.index(i, k)] * self.band[self.index(j, k)];
                }
                let idx = self.index(i, j);
                if i == j {
                    if s.is_nan() || s <= 0.0 {
                        return None;
                    }
                    self.band[idx] = s.sqrt();
                } else {
                    self.band[idx] = s / self.band[self.index(j, j)];
                }
            }
        }
        Some(BandCholesky { factor: self })
    }
}

/// The factor of [`BandMatrix::cholesky`].
#[derive(Debug, Clone)]
pub struct BandCholesky {
    factor: BandMatrix,
}

impl BandCholesky {
    /// Solves `A x = b` in place.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let l = &self.factor;
        let w = l.half_bandwidth;
        for i in 0..l.n {
            let mut s = b[i];
            let start = i.saturating_sub(w);
            for (k, bk) in b.iter().enumerate().take(i).skip(start) {
                s -= l.band[l.index(i, k)] * bk;
            }
            b[i] = s / l.band[l.index(i, i)];
        }
        for i in (0..l.n).rev() {
            let mut s = b[i];
            for (k, bk) in b.iter().enumerate().take((i + w + 1).min(l.n)).skip(i + 1) {
                s -= l.band[l.index(k, i)] * bk;
            }
            b[i] = s / l.band[l.index(i, i)];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    #[test]
    fn matches_a_dense_solve() {
        let (n, w) = (40, 5);
        let mut band = BandMatrix::zeros(n, w);
        let mut dense = DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            for j in i.saturating_sub(w)..=i {
                let v = if i == j {
                    10.0 + i as f64 * 0.1
                } else {
                    ((i * 7 + j * 3) % 5) as f64 * 0.3 - 0.6
                };
                band.add(i, j, v);
                dense[(i, j)] = v;
                dense[(j, i)] = v;
            }
        }
        let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        let mut x = b.clone();
        band.cholesky()
            .expect("diagonally dominant")
            .solve_in_place(&mut x);
        let expected = dense.lu().solve(&DVector::from_vec(b)).expect("invertible");
        for (a, e) in x.iter().zip(expected.iter()) {
            assert!((a - e).abs() < 1e-12, "{a} vs {e}");
        }
    }
}
