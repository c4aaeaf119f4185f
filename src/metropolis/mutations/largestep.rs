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

pub struct LargeStep;

/// p(y): the density of the whole path `path` under the large step, whatever the current path was.
pub fn density(scene: &Scene, bdpt: &Bdpt, path: &[Vertex]) -> f64 {
    if path.len() < 2 {
        return 0.0;
    }
    let (k_min, k_max) = edge_range(bdpt);
    let p_length = two_tailed_pmf(LENGTH_CENTRE, k_min, k_max, path.len() - 1);
    // Keeping x_0 alone, all edges after it are new, counting the light supernode's edge.
    p_length * regrowth_density(scene, path, 0, path.len())
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
        let (k_min, k_max) = edge_range(ctx.bdpt);
        let k_new =
            sample_two_tailed(LENGTH_CENTRE, k_min, k_max, rng.next_f64()).ok_or(Failure::NotApplicable)?;
        let y = regrow(ctx, x, 0, x.len(), k_new + 1, rng)?;
        if y.len() > ctx.max_vertices() || y.len() != k_new + 1 {
            return Err(Failure::Failed("too_long"));
        }
        let state = PathState::new(ctx.scene, y).ok_or(Failure::Failed("zero_contribution"))?;
        let forward = density(ctx.scene, ctx.bdpt, &state.vertices);
        let reverse = density(ctx.scene, ctx.bdpt, x);
        let t_ratio = reverse / forward;
        if !(forward > 0.0 && forward.is_finite() && reverse.is_finite() && t_ratio.is_finite()) {
            return Err(Failure::Failed("degenerate_density"));
        }
        stats.add_sum("new_edges", k_new as f64);
        Ok(Proposal { state, t_ratio })
    }
}
