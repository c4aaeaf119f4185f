//! The normalisation b of path-space MLT (Veach 1997, §11.3.3): the integral of the chains' target
//! over path space. The seeding pass's BDPT samples estimate it; every large step's f(y)/p(y) is a
//! second, independent estimate, recorded beside it but not mixed in (docs/mlt.md, "b").

use super::chain::MutationStats;
use super::mutations::largestep;
use super::mutations::MutationKind;

/// The two estimates of b side by side, each with its relative standard error (the seeding pass's
/// from `PathSeeds::b_standard_error`). They should agree within a few standard errors, but the large
/// step's is heavy-tailed: most renders see it low and a few far too high.
pub fn metadata(seed_b: f64, seed_standard_error: f64, stats: &[MutationStats]) -> Vec<(String, String)> {
    let seed_error = seed_standard_error / seed_b;
    let mut out = vec![("hslt.mlt.b_seed_relative_error".to_string(), format!("{seed_error:.3e}"))];
    let large = LargeStepSums::of(stats);
    if large.n > 1 {
        let mean = large.sum / large.n as f64;
        let variance = (large.squares / large.n as f64 - mean * mean).max(0.0);
        out.push(("hslt.mlt.b_large".into(), format!("{mean:.6e}")));
        out.push((
            "hslt.mlt.b_large_relative_error".into(),
            format!("{:.3e}", (variance / large.n as f64).sqrt() / mean),
        ));
        out.push(("hslt.mlt.b_large_samples".into(), large.n.to_string()));
    }
    out
}

/// Σ f(y)/p(y), Σ (f(y)/p(y))² and the count over every large step proposed (failures count 0).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LargeStepSums {
    pub sum: f64,
    pub squares: f64,
    pub n: u64,
}

impl LargeStepSums {
    pub fn of(stats: &[MutationStats]) -> LargeStepSums {
        stats.iter().filter(|s| s.name == MutationKind::LargeStep.name()).fold(
            LargeStepSums::default(),
            |acc, s| {
                let get = |k| s.sums.get(k).copied().unwrap_or(0.0);
                LargeStepSums {
                    sum: acc.sum + get(largestep::B_ESTIMATE),
                    squares: acc.squares + get(largestep::B_ESTIMATE_SQUARES),
                    n: acc.n + s.proposed,
                }
            },
        )
    }
}
