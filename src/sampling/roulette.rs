//! Russian roulette (Arvo and Kirk 1990; Veach 1997 §10.4.1): a path continues with probability q and
//! its throughput is divided by q, so the estimate stays unbiased. The path tracer and the BDPT
//! sub-path walk (and so PSSMLT and the path-space seeding pass) share this rule.

/// The largest survival probability. The cap bounds a path's expected length in a lossless trap (a
/// photon caught between mirrors or inside glass by total internal reflection), but every lossless
/// bounce past `rr_depth` multiplies the surviving path's weight by 1/cap: after n such bounces its
/// variance grows by cap^-n. Mitsuba 3's 0.95 gives 36× the weight after the 70 bounces a path
/// caught in one of jewelry's gems can make (the 77-vertex seed path that held 1.2% of b, docs/mlt.md);
/// 0.99 gives 2×, for at most five times the bounces in such traps. Walks on surfaces that absorb 5% or
/// more end as before, provided the throughput is judged relative to the walk's start: a light walk's
/// starts at Le·cos/pdf, often far above 1, and judged absolutely it ran to the cap everywhere (the
/// closed-sphere analytic tests' BDPT took 1.6× longer, docs/benchmarks.md). pbrt-v4 never caps (q = 1
/// while the throughput is at least 1) and bounds the depth instead, which our unbounded
/// `max_depth = -1` cannot do.
///
/// Measured (64×48, 2 threads, 20 s, seeds 1–3, against two 150-s BDPT renders; docs/benchmarks.md):
/// jewelry `pt` relative MSE 3.3, 4.0, 3.9e-3 → 2.6, 2.4, 2.6e-3 at the same samples per pixel, `bdpt`
/// 2.8, 2.2, 1.7e-3 → 2.2, 2.0, 1.6e-3, `hslt` (seeds 1–4) 5.5, 7.4, 3.5, 6.2e-3 → 4.6, 5.9, 4.2,
/// 4.8e-3; the seeding pass's variance per sample 1.6× lower. 0.999 was no better than 0.99 for `pt`.
pub const MAX_SURVIVAL: f32 = 0.99;

/// The probability that a path continues, given the largest component of its throughput times the
/// squared relative index of refraction it has crossed (so entering a denser medium, which scales
/// radiance by 1/η², is not mistaken for loss): that value, capped at `MAX_SURVIVAL`. NaN gives 0.
pub fn survival_probability(throughput_eta2: f32) -> f32 {
    if throughput_eta2 >= 0.0 {
        throughput_eta2.min(MAX_SURVIVAL)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn survival_follows_the_throughput_up_to_the_cap() {
        assert_eq!(survival_probability(0.3), 0.3);
        assert_eq!(survival_probability(5.0), MAX_SURVIVAL);
        assert_eq!(survival_probability(f32::NAN), 0.0);
        assert_eq!(survival_probability(-1.0), 0.0);
    }

    #[test]
    fn a_lossless_trap_of_seventy_bounces_at_most_doubles_the_weight() {
        // The weight a surviving path carries out of 70 lossless bounces (jewelry's gem trap).
        let amplification = survival_probability(1.0).powi(-70);
        assert!(amplification < 2.1, "70 lossless bounces amplify a path's weight {amplification}×");
    }
}
