//! The large step: an independent proposal of a whole new path (Kelemen et al. 2002 in primary sample
//! space; in path space the independence sampler of Veach 1997, §11.3, with [C13]'s "largestep"): keep
//! only the pinhole x_0 and regrow everything by the bidirectional mutation's sampler, with the new
//! length drawn from a fixed distribution, so T(x→y) = p(y) and the ratio is p(x)/p(y).
//!
//! Why path space wants it: every other mutation keeps most of the path, so a chain explores the image
//! and the families of paths only by small moves; the large step lets chains jump anywhere, and with
//! expected-value recording even its rejected proposals add their sample to the image.

use super::bidir::{edge_range, regrow, regrowth_density, sample_two_tailed, two_tailed_pmf};
use crate::integrators::Bdpt;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;

/// The edge count new paths are centred on: the two-tailed geometric pmf ∝ 2^−|k − 2| gives the direct
/// and one-bounce lengths most of the mass and halves it per further bounce.
const LENGTH_CENTRE: usize = 2;

/// Share of the seeding pass's length histogram in `LengthPmf`; the rest is the two-tailed pmf, which
/// keeps every length in reach.
pub const SEEDED_LENGTH_SHARE: f64 = 0.5;

/// The distribution of the new path's edge count: the two-tailed pmf alone, or mixed with the share of
/// the image each length carried in the seeding pass (`PathSeeds::by_edges`). An independence sampler
/// leaves a state at a rate set by f(x)/p(x), so a length the fixed pmf gives 2^−38 (the diamond's
/// 40-edge paths) would hold any chain that reaches it; the histogram gives it the share of light it
/// carries. The histogram is fixed before the chains start, so the kernel stays a fixed density.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LengthPmf {
    /// Normalised seeded share by edge count (empty: the two-tailed pmf alone).
    seeded: Vec<f64>,
}

impl LengthPmf {
    /// From luminance sums by edge count; lengths outside [k_min, k_max] are dropped.
    pub fn from_histogram(by_edges: &[f64], bdpt: &Bdpt) -> LengthPmf {
        let (k_min, k_max) = edge_range(bdpt);
        let mut seeded: Vec<f64> = by_edges
            .iter()
            .enumerate()
            .map(|(k, &w)| if k >= k_min && k <= k_max && w.is_finite() && w > 0.0 { w } else { 0.0 })
            .collect();
        let total: f64 = seeded.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return LengthPmf::default();
        }
        seeded.iter_mut().for_each(|w| *w /= total);
        LengthPmf { seeded }
    }

    fn seeded_share(&self) -> f64 {
        if self.seeded.is_empty() {
            0.0
        } else {
            SEEDED_LENGTH_SHARE
        }
    }

    /// P(k edges).
    pub fn pmf(&self, bdpt: &Bdpt, k: usize) -> f64 {
        let (k_min, k_max) = edge_range(bdpt);
        let share = self.seeded_share();
        let seeded = self.seeded.get(k).copied().unwrap_or(0.0);
        share * seeded + (1.0 - share) * two_tailed_pmf(LENGTH_CENTRE, k_min, k_max, k)
    }

    fn sample(&self, bdpt: &Bdpt, rng: &mut Sampler) -> Option<usize> {
        let (k_min, k_max) = edge_range(bdpt);
        let u = rng.next_f64();
        if rng.next_f64() < self.seeded_share() {
            let mut rest = u;
            for (k, &p) in self.seeded.iter().enumerate() {
                rest -= p;
                if rest < 0.0 && p > 0.0 {
                    return Some(k);
                }
            }
            return self.seeded.iter().rposition(|&p| p > 0.0);
        }
        sample_two_tailed(LENGTH_CENTRE, k_min, k_max, u)
    }
}

/// The `MutationStats::sums` key of Σ luminance f(y) / p(y) over the proposals.
pub const B_ESTIMATE: &str = "b_estimate";

/// The large step with its length distribution.
#[derive(Clone, Debug, Default)]
pub struct LargeStep {
    pub lengths: LengthPmf,
}

impl LargeStep {
    /// p(y): the density of the whole path `path` under the large step, whatever the current path was.
    pub fn density(&self, scene: &Scene, bdpt: &Bdpt, path: &[Vertex]) -> f64 {
        if path.len() < 2 {
            return 0.0;
        }
        let p_length = self.lengths.pmf(bdpt, path.len() - 1);
        // Keeping x_0 alone, all edges after it are new, counting the light supernode's edge.
        p_length * regrowth_density(scene, path, 0, path.len())
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
        let k_new = self.lengths.sample(ctx.bdpt, rng).ok_or(Failure::NotApplicable)?;
        let y = regrow(ctx, x, 0, x.len(), k_new + 1, rng)?;
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
        // luminance f(y) / p(y) is an unbiased estimate of b (failed proposals count 0): the render
        // refines the seeding pass's b with it, as PSSMLT does with its large steps.
        stats.add_sum(B_ESTIMATE, state.luminance() / forward);
        Ok(Proposal { state, t_ratio })
    }
}
