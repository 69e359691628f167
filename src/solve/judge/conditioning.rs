//! Conditioning of the stacked `T` (MODEL.md "Metrics"): singular values,
//! `kappa = sigma_max / sigma_min` (infinite when rank-deficient, never NaN)
//! and the numerical rank at the same threshold.

use crate::solve::SolveError;
use crate::transport::Transport;

/// MODEL.md's relative rank tolerance per dimension: a singular value counts
/// as zero at or below `sigma_max * max(M, N) * RANK_EPS`.
pub(crate) const RANK_EPS: f64 = 2.2e-16;

/// Singular spectrum of `T` and what follows from it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Conditioning {
    /// Rows of `T`.
    pub rows: usize,
    /// Columns of `T`.
    pub cols: usize,
    /// Singular values, non-increasing.
    pub singular_values: Vec<f64>,
    /// `sigma_max / sigma_min`, or infinity (serialized as the string `"inf"`).
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa: f64,
    /// Number of singular values above the threshold.
    pub rank: usize,
    /// `sigma_max * max(M, N) * 2.2e-16`; from the Gram ([`Self::from_low_rank`]),
    /// its resolution when larger.
    pub threshold: f64,
    /// Whether the spectrum comes from `T^T T` (resolved down to `threshold`
    /// only) rather than from an SVD of `T`.
    #[serde(skip)]
    pub from_gram: bool,
}

impl Conditioning {
    /// From singular values of an `rows x cols` matrix, sorted non-increasing.
    pub fn from_singular_values(rows: usize, cols: usize, singular_values: Vec<f64>) -> Self {
        let smax = singular_values.first().copied().unwrap_or(0.0);
        let threshold = smax * rows.max(cols) as f64 * RANK_EPS;
        let rank = singular_values.iter().filter(|&&s| s > threshold).count();
        let smin = singular_values.last().copied().unwrap_or(0.0);
        let kappa = if rows < cols || smax == 0.0 || smin <= threshold {
            f64::INFINITY
        } else {
            smax / smin
        };
        Self {
            rows,
            cols,
            singular_values,
            kappa,
            rank,
            threshold,
            from_gram: false,
        }
    }

    /// From the low-rank form of `T^T T` (no SVD of `T`): the singular values
    /// it resolves, those at or below its resolution (`sqrt` of the trace it
    /// leaves out, by Weyl's inequality) counted as zero. Rank and kappa are
    /// then those of `T` to that resolution, about 1e-7 of `sigma_max` instead
    /// of the SVD's 1e-12: a `T` with singular values in between reads as
    /// rank-deficient, which it is for every noise level a camera reaches.
    pub fn from_low_rank(
        rows: usize,
        cols: usize,
        low_rank: &crate::solve::lowrank::LowRank,
    ) -> Result<Self, SolveError> {
        let s = low_rank.singular_values()?;
        let smax = s.first().copied().unwrap_or(0.0);
        let threshold = low_rank
            .remainder
            .max(0.0)
            .sqrt()
            .max(smax * rows.max(cols) as f64 * RANK_EPS);
        let mut singular_values: Vec<f64> = s.into_iter().filter(|&v| v > threshold).collect();
        singular_values.resize(rows.min(cols).max(singular_values.len()), 0.0);
        let mut c = Self::from_singular_values(rows, cols, singular_values);
        if c.threshold < threshold {
            c.threshold = threshold;
            c.rank = c.singular_values.iter().filter(|&&v| v > threshold).count();
            let smin = c.singular_values.last().copied().unwrap_or(0.0);
            if smin <= threshold {
                c.kappa = f64::INFINITY;
            }
        }
        c.from_gram = true;
        Ok(c)
    }

    /// Whether `T` is rank-deficient (kappa infinite).
    pub fn is_rank_deficient(&self) -> bool {
        self.kappa.is_infinite()
    }

    /// The per-element RMS error of the least-squares solution under white
    /// noise of standard deviation `sigma`: `sigma sqrt(mean_i 1/s_i^2)`
    /// (infinite when rank-deficient). The `polnlos grid` criterion.
    pub fn noise_amplification(&self, sigma: f64) -> f64 {
        if self.is_rank_deficient() {
            return f64::INFINITY;
        }
        let inv: f64 = self.singular_values.iter().map(|s| 1.0 / (s * s)).sum();
        sigma * (inv / self.cols as f64).sqrt()
    }
}

/// Computes the singular values of `T` with faer.
pub fn condition(t: &Transport) -> Result<Conditioning, SolveError> {
    let s = t
        .as_mat()
        .singular_values()
        .map_err(|e| SolveError::Factorization(format!("SVD of T did not converge ({e:?})")))?;
    Ok(Conditioning::from_singular_values(t.rows(), t.cols(), s))
}

/// [`condition`], or, when `gram` has a low-rank form, the spectrum it
/// resolves ([`Conditioning::from_low_rank`], no SVD of `T`).
pub fn condition_with(
    t: &Transport,
    gram: Option<&crate::solve::gram::Gram>,
) -> Result<Conditioning, SolveError> {
    match gram.and_then(|g| g.low_rank.as_ref()) {
        Some(lr) => Conditioning::from_low_rank(t.rows(), t.cols(), lr),
        None => condition(t),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kappa_rules() {
        let c = Conditioning::from_singular_values(4, 2, vec![2.0, 0.5]);
        assert_eq!(c.kappa, 4.0);
        assert_eq!(c.rank, 2);
        let c = Conditioning::from_singular_values(4, 2, vec![2.0, 0.0]);
        assert!(c.kappa.is_infinite() && c.rank == 1);
        let c = Conditioning::from_singular_values(4, 2, vec![2.0, 2.0 * 4.0 * 1e-16]);
        assert!(c.kappa.is_infinite(), "below the threshold counts as zero");
        let c = Conditioning::from_singular_values(1, 2, vec![1.0]);
        assert!(c.kappa.is_infinite(), "fewer rows than columns");
        let c = Conditioning::from_singular_values(3, 3, vec![0.0, 0.0, 0.0]);
        assert!(c.kappa.is_infinite() && !c.kappa.is_nan());
    }
}
