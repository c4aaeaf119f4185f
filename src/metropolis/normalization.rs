//! The normalisation b of path-space MLT (Veach 1997, §11.3.3): the integral of the chains' target
//! over path space. The seeding pass's BDPT samples estimate it; every large step's f(y)/p(y) is a
//! second, independent estimate, recorded beside it but not mixed in (docs/mlt.md, "Why b comes from
//! the seeding pass alone").

use super::chain::MutationStats;
use super::mutations::largestep;
use super::mutations::MutationKind;

/// The two estimates of b side by side, each with its relative standard error (the seeding pass's
/// from `PathSeeds::b_standard_error`). They should agree within a few standard errors, but the large
/// step's is heavy-tailed: most renders see it low and a few far too high. Large steps that all
/// failed (an estimate of 0) leave only the seeding pass's entry.
pub fn metadata(seed_b: f64, seed_standard_error: f64, stats: &[MutationStats]) -> Vec<(String, String)> {
    let seed_error = seed_standard_error / seed_b;
    let mut out = vec![("hslt.mlt.b_seed_relative_error".to_string(), format!("{seed_error:.3e}"))];
    let (sum, squares, n) = stats.iter().filter(|s| s.name == MutationKind::LargeStep.name()).fold(
        (0.0, 0.0, 0u64),
        |(sum, squares, n), s| {
            let get = |k| s.sums.get(k).copied().unwrap_or(0.0);
            (sum + get(largestep::B_ESTIMATE), squares + get(largestep::B_ESTIMATE_SQUARES), n + s.proposed)
        },
    );
    let mean = sum / n.max(1) as f64;
    if n > 1 && mean > 0.0 && mean.is_finite() {
        let variance = (squares / n as f64 - mean * mean).max(0.0);
        out.push(("hslt.mlt.b_large".into(), format!("{mean:.6e}")));
        out.push((
            "hslt.mlt.b_large_relative_error".into(),
            format!("{:.3e}", (variance / n as f64).sqrt() / mean),
        ));
        out.push(("hslt.mlt.b_large_samples".into(), n.to_string()));
    }
    out
}
