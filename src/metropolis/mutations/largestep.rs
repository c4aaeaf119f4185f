//! The large step: an independent proposal of a whole new path (Kelemen et al. 2002 in primary sample
//! space; in path space the independence sampler of Veach 1997, §11.3, with [C13]'s "largestep"): keep
//! only the pinhole x_0 and regrow everything by the bidirectional mutation's sampler, with the new
//! length and split (BDPT's strategy) drawn from a fixed distribution, so T(x→y) = p(y) and the ratio
//! is p(x)/p(y).
//!
//! Why path space wants it: every other mutation keeps most of the path, so a chain explores the image
//! and the families of paths only by small moves; the large step lets chains jump anywhere, and with
//! expected-value recording even its rejected proposals add their sample to the image.

use super::bidir::{edge_range, regrow_split, sample_two_tailed, split_densities, two_tailed_pmf};
use crate::integrators::Bdpt;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;

/// The edge count new paths are centred on: the two-tailed geometric pmf ∝ 2^−|k − 2| gives the direct
/// and one-bounce lengths most of the mass and halves it per further bounce.
const LENGTH_CENTRE: usize = 2;

/// Share of the seeding pass's strategy histogram in `StrategyPmf`; the rest is the two-tailed length
/// pmf with a uniform split, which keeps every strategy of every length in reach.
pub const SEEDED_STRATEGY_SHARE: f64 = 0.5;

/// The distribution of the new path's edge count k and split s (s of the k + 1 new vertices grown from
/// the light, the rest from the camera; BDPT's strategy (s, t = k + 1 − s)): the two-tailed length pmf
/// with a uniform split alone, or mixed with the share of the image each strategy carried, MIS-weighted,
/// in the seeding pass (`PathSeeds::by_strategy`). An independence sampler leaves a state at a rate set
/// by f(x)/p(x), so
/// - a length the fixed pmf gives 2^−38 (the diamond's 40-edge paths) would hold any chain that
///   reaches it; the histogram gives it the share of light it carries;
/// - a split drawn uniformly spends most proposals on strategies that carry no light where they are
///   poor (on the open rings scene 86% of large steps ended in a walk that left the scene, and 0.3%
///   were accepted); the histogram proposes the way BDPT's MIS weights say each length is best made.
///
/// The histogram is fixed before the chains start, so the kernel stays a fixed density.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StrategyPmf {
    /// Normalised seeded share by edge count k and split s (`seeded[k][s]`; empty: the fixed pmf alone).
    seeded: Vec<Vec<f64>>,
}

impl StrategyPmf {
    /// From luminance sums by edge count and split (`by_strategy[k][s]`); strategies outside
    /// [k_min, k_max] × [0, k] are dropped.
    pub fn from_histogram(by_strategy: &[Vec<f64>], bdpt: &Bdpt) -> StrategyPmf {
        let (k_min, k_max) = edge_range(bdpt);
        let mut seeded: Vec<Vec<f64>> = by_strategy
            .iter()
            .enumerate()
            .map(|(k, splits)| {
                let keep = |s: usize, w: f64| k >= k_min && k <= k_max && s <= k && w.is_finite() && w > 0.0;
                splits.iter().enumerate().map(|(s, &w)| if keep(s, w) { w } else { 0.0 }).collect()
            })
            .collect();
        let total: f64 = seeded.iter().flatten().sum();
        if !(total > 0.0 && total.is_finite()) {
            return StrategyPmf::default();
        }
        seeded.iter_mut().flatten().for_each(|w| *w /= total);
        StrategyPmf { seeded }
    }

    fn seeded_share(&self) -> f64 {
        if self.seeded.is_empty() {
            0.0
        } else {
            SEEDED_STRATEGY_SHARE
        }
    }

    /// P(k edges).
    pub fn length_pmf(&self, bdpt: &Bdpt, k: usize) -> f64 {
        (0..=k).map(|s| self.pmf(bdpt, k, s)).sum()
    }

    /// P(k edges, split s).
    pub fn pmf(&self, bdpt: &Bdpt, k: usize, s: usize) -> f64 {
        if s > k {
            return 0.0;
        }
        let (k_min, k_max) = edge_range(bdpt);
        let share = self.seeded_share();
        let seeded = self.seeded.get(k).and_then(|splits| splits.get(s)).copied().unwrap_or(0.0);
        let fixed = two_tailed_pmf(LENGTH_CENTRE, k_min, k_max, k) / (k + 1) as f64;
        share * seeded + (1.0 - share) * fixed
    }

    /// A strategy (k, s).
    fn sample(&self, bdpt: &Bdpt, rng: &mut Sampler) -> Option<(usize, usize)> {
        let (k_min, k_max) = edge_range(bdpt);
        let u = rng.next_f64();
        let v = rng.next_f64();
        if rng.next_f64() < self.seeded_share() {
            let mut rest = u;
            let mut last = None;
            for (k, splits) in self.seeded.iter().enumerate() {
                for (s, &p) in splits.iter().enumerate() {
                    if p > 0.0 {
                        last = Some((k, s));
                        rest -= p;
                        if rest < 0.0 {
                            return last;
                        }
                    }
                }
            }
            return last;
        }
        let k = sample_two_tailed(LENGTH_CENTRE, k_min, k_max, u)?;
        Some((k, ((v * (k + 1) as f64) as usize).min(k)))
    }
}

/// The `MutationStats::sums` key of Σ luminance f(y) / p(y) over the proposals.
pub const B_ESTIMATE: &str = "b_estimate";

/// The `MutationStats::sums` key of Σ (luminance f(y) / p(y))²: the variance of `B_ESTIMATE`'s terms.
pub const B_ESTIMATE_SQUARES: &str = "b_estimate_squares";

/// The large step with its distribution of lengths and splits.
#[derive(Clone, Debug, Default)]
pub struct LargeStep {
    pub strategies: StrategyPmf,
}

impl LargeStep {
    /// p(y): the density of the whole path `path` under the large step, whatever the current path was:
    /// Σ_s P(k, s) p_s(y) over the splits that could have made it.
    pub fn density(&self, scene: &Scene, bdpt: &Bdpt, path: &[Vertex]) -> f64 {
        if path.len() < 2 {
            return 0.0;
        }
        let k = path.len() - 1;
        // Keeping x_0 alone, all edges after it are new, counting the light supernode's edge.
        split_densities(scene, path, 0, path.len())
            .iter()
            .enumerate()
            .map(|(s, p_s)| self.strategies.pmf(bdpt, k, s) * p_s)
            .sum()
    }
}

impl<'a> Mutation<PathState, PathContext<'a>> for LargeStep {
    fn name(&self) -> &'static str {
        "largestep"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let x = &current.vertices;
        if x.len() < 2 {
            return Err(Failure::NotApplicable);
        }
        let (k_new, split) = self.strategies.sample(ctx.bdpt, rng).ok_or(Failure::NotApplicable)?;
        let y = regrow_split(ctx, x, 0, x.len(), k_new + 1, split, rng)?;
        if y.len() > ctx.max_vertices() || y.len() != k_new + 1 {
            return Err(Failure::Failed("too_long"));
        }
        let state = PathState::new(ctx.scene, y).ok_or(Failure::Failed("zero_contribution"))?;
        let forward = self.density(ctx.scene, ctx.bdpt, &state.vertices);
        let reverse = self.density(ctx.scene, ctx.bdpt, x);
        let t_ratio = reverse / forward;
        if !(forward > 0.0 && forward.is_finite() && reverse.is_finite() && t_ratio.is_finite()) {
            return Err(Failure::Failed("degenerate_density"));
        }
        stats.add_sum("new_edges", k_new as f64);
        // luminance f(y) / p(y) is an unbiased estimate of b (failed proposals count 0), recorded
        // beside the seeding pass's but not mixed into it: p(y) carries the strategy's pmf, so its
        // tail is far heavier (`metropolis::normalization`).
        let estimate = state.luminance() / forward;
        stats.add_sum(B_ESTIMATE, estimate);
        stats.add_sum(B_ESTIMATE_SQUARES, estimate * estimate);
        Ok(Proposal { state, t_ratio })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::DepthLimits;

    fn bdpt(max_depth: i32, min_path_vertices: usize) -> Bdpt {
        let mut bdpt = Bdpt::new(DepthLimits { max_depth, rr_depth: 5 }, false);
        bdpt.min_path_vertices = min_path_vertices;
        bdpt
    }

    #[test]
    fn strategies_are_normalised_sampled_by_their_pmf_and_keep_every_strategy_in_reach() {
        let bdpt = bdpt(8, 4);
        // Lengths 0-2 lie below the chains' support (the direct pass has them) and s = 5 > k = 4 is
        // no strategy: both are dropped; k = 3, s = 1 and k = 4, s = 4 carry the seeded light.
        let histogram =
            vec![vec![9.0], vec![], vec![5.0, 5.0], vec![0.0, 3.0], vec![0.0, 0.0, 0.0, 0.0, 1.0, 7.0]];
        let pmf = StrategyPmf::from_histogram(&histogram, &bdpt);
        let (k_min, k_max) = edge_range(&bdpt);
        assert_eq!((k_min, k_max), (3, 8));
        let all: Vec<(usize, usize)> =
            (0..=k_max + 1).flat_map(|k| (0..=k + 1).map(move |s| (k, s))).collect();
        let total: f64 = all.iter().map(|&(k, s)| pmf.pmf(&bdpt, k, s)).sum();
        assert!((total - 1.0).abs() < 1e-12, "sums to {total}");
        for &(k, s) in &all {
            let p = pmf.pmf(&bdpt, k, s);
            let in_range = (k_min..=k_max).contains(&k) && s <= k;
            assert_eq!(p > 0.0, in_range, "({k}, {s}): {p}");
        }
        // Half the mass is the seeded share, split 3 : 1 between its two strategies.
        let fixed = |k: usize| two_tailed_pmf(LENGTH_CENTRE, k_min, k_max, k) / (k + 1) as f64;
        assert!((pmf.pmf(&bdpt, 3, 1) - (0.5 * 0.75 + 0.5 * fixed(3))).abs() < 1e-12);
        assert!((pmf.pmf(&bdpt, 4, 4) - (0.5 * 0.25 + 0.5 * fixed(4))).abs() < 1e-12);
        assert!((pmf.length_pmf(&bdpt, 3) - (0.5 * 0.75 + 0.5 * 4.0 * fixed(3))).abs() < 1e-12);
        // Frequencies of 40 000 draws within 5 binomial standard deviations of the pmf.
        let n = 40_000;
        let mut rng = Sampler::new(3, 0, 0);
        let mut counts = std::collections::HashMap::new();
        for _ in 0..n {
            *counts.entry(pmf.sample(&bdpt, &mut rng).expect("a strategy")).or_insert(0usize) += 1;
        }
        for &(k, s) in &all {
            let p = pmf.pmf(&bdpt, k, s);
            let count = counts.get(&(k, s)).copied().unwrap_or(0) as f64;
            let sd = (n as f64 * p * (1.0 - p)).sqrt();
            assert!((count - n as f64 * p).abs() <= 5.0 * sd + 1.0, "({k}, {s}): {count} draws, p = {p}");
        }
    }

    #[test]
    fn an_empty_or_unusable_histogram_leaves_the_fixed_pmf() {
        let bdpt = bdpt(-1, 4);
        assert_eq!(StrategyPmf::from_histogram(&[], &bdpt), StrategyPmf::default());
        let below_support = vec![vec![1.0], vec![1.0, 1.0], vec![f64::NAN, 2.0, 1.0]];
        assert_eq!(StrategyPmf::from_histogram(&below_support, &bdpt), StrategyPmf::default());
        let fixed = StrategyPmf::default();
        let (k_min, k_max) = edge_range(&bdpt);
        let total: f64 = (k_min..=k_max).map(|k| fixed.length_pmf(&bdpt, k)).sum();
        assert!((total - 1.0).abs() < 1e-9, "sums to {total}");
    }
}
