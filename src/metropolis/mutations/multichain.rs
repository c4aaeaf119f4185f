//! Veach's multi-chain perturbation (Veach 1997, §11.4.4; Mitsuba's `mut_mchain.cpp`): a lens
//! perturbation whose first non-specular vertex y_c is followed by another specular chain; the old
//! outgoing direction at y_c is turned by a tiny angle and the next chain retraced, and so on, until
//! the path can be reconnected to its unchanged rest or ends on the emitter.
//!
//! | parameter | value | meaning |
//! |---|---|---|
//! | r1, r2 | as the lens perturbation (`perturb::FILM_R1_PIXELS`, `perturb::FILM_R2_AREA_FRACTION`) | film offset |
//! | θ1 | `THETA1_DEGREES` = 0.0001° | smallest turn of each later chain's direction |
//! | θ2 | `THETA2_DEGREES` = 0.1° | largest turn |
//! | angle density | ∝ 1/θ on [θ1, θ2], uniform azimuth | the same range both ways, so it cancels |
//!
//! T(y→x)/T(x→y) = pdf_dir(x_0→x_1)/pdf_dir(y_0→y_1) · Π conv(x) / Π conv(y) over every traced vertex.

use super::perturb::{
    camera_chain_density, connect_visible, conversion_product, first_non_delta, perturb_direction, ray_from,
    sample_film_offset, trace_from_camera, trace_specular_chain,
};
use crate::bsdf::TransportMode;
use crate::geometry::{Vec2, Vec3};
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;

/// Smallest angle by which each later chain's direction is turned (the range issue #6 specifies).
pub const THETA1_DEGREES: f64 = 0.0001;
/// Largest angle by which each later chain's direction is turned.
pub const THETA2_DEGREES: f64 = 0.1;

/// Where the chains of a path lie: the first non-specular vertex c after the camera, then each later
/// specular chain as (a, b): it leaves the non-specular y_a and ends at the next non-specular vertex
/// (or the emitter end) b. `ends_on_emitter` when the last chain reaches x_k, else x_b joins x_{b+1}.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChainLayout {
    pub c: usize,
    pub chains: Vec<(usize, usize)>,
    pub ends_on_emitter: bool,
}

/// The multi-chain perturbation (stateless).
#[derive(Clone, Copy, Debug, Default)]
pub struct MultiChainPerturbation;

impl MultiChainPerturbation {
    /// The layout of `x` if the perturbation applies: the camera's chain ends at a non-specular,
    /// scattering x_c followed by a specular x_{c+1}.
    pub fn applicable(scene: &Scene, x: &[Vertex]) -> Option<ChainLayout> {
        let n = x.len();
        let k = n.checked_sub(1)?;
        let c = first_non_delta(x, 1)?;
        if c >= k || !x[c + 1].delta {
            return None;
        }
        let scatters = |v: &Vertex| v.kind == VertexKind::Surface && v.connectible();
        if !scatters(&x[c]) {
            return None;
        }
        let mut chains = Vec::new();
        let mut a = c;
        loop {
            let b = first_non_delta(x, a + 1).unwrap_or(k);
            chains.push((a, b));
            if b == k {
                let end = &x[k];
                let hittable = end.light.is_some() && !end.is_delta_light(scene) && !end.delta;
                return hittable.then_some(ChainLayout { c, chains, ends_on_emitter: true });
            }
            if x[b + 1].delta {
                if !scatters(&x[b]) {
                    return None;
                }
                a = b;
                continue;
            }
            return (x[b].kind == VertexKind::Surface && x[b].connectible() && x[b + 1].connectible())
                .then_some(ChainLayout { c, chains, ends_on_emitter: false });
        }
    }
}

impl MultiChainPerturbation {
    /// The deterministic part of the move: the path of `current` re-seen through film position
    /// `film`, each later chain leaving its new start along `turn(old direction)`, with
    /// T(y→x)/T(x→y) (the turns' density is the same both ways and cancels). Tests call it to retrace
    /// a proposal back to where it came from.
    pub fn perturb_with(
        &self,
        ctx: &mut PathContext,
        current: &PathState,
        film: Vec2,
        mut turn: impl FnMut(Vec3) -> Vec3,
    ) -> Result<Proposal<PathState>, Failure> {
        let x = &current.vertices;
        let n = x.len();
        if n > ctx.max_vertices() {
            return Err(Failure::NotApplicable);
        }
        let layout = Self::applicable(ctx.scene, x).ok_or(Failure::NotApplicable)?;
        let mut y = trace_from_camera(ctx, x, layout.c, film)?;
        let scene = ctx.scene;
        let mut density_y = camera_chain_density(scene, &y);
        let mut density_x = camera_chain_density(scene, &x[..=layout.c]);
        for &(a, b) in &layout.chains {
            if !y[a].connectible() {
                return Err(Failure::Failed("not_connectible"));
            }
            let w = turn(x[a].direction_to(&x[a + 1]));
            let ray = ray_from(&y[a], w);
            let ends_on_emitter = layout.ends_on_emitter && b == n - 1;
            let traced = trace_specular_chain(ctx, &x[a..=b], ray, TransportMode::Radiance, ends_on_emitter)?;
            y.extend(traced);
            density_y *= conversion_product(scene, &y[a..=b]);
            density_x *= conversion_product(scene, &x[a..=b]);
        }
        if !layout.ends_on_emitter {
            let b = y.len() - 1;
            if !y[b].connectible() {
                return Err(Failure::Failed("not_connectible"));
            }
            if !connect_visible(ctx, &y[b], &x[b + 1]) {
                return Err(Failure::Failed("occluded"));
            }
            y.extend_from_slice(&x[b + 1..]);
        }
        if !(density_y > 0.0 && density_y.is_finite()) {
            return Err(Failure::Failed("zero_density"));
        }
        let state = PathState::new(scene, y).ok_or(Failure::Failed("no_contribution"))?;
        Ok(Proposal { state, t_ratio: density_x / density_y })
    }
}

impl<'a> Mutation<PathState, PathContext<'a>> for MultiChainPerturbation {
    fn name(&self) -> &'static str {
        "multichain"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        _stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        if Self::applicable(ctx.scene, &current.vertices).is_none() {
            return Err(Failure::NotApplicable);
        }
        let film = current.film + sample_film_offset(ctx.scene, rng);
        let (theta1, theta2) = (THETA1_DEGREES.to_radians(), THETA2_DEGREES.to_radians());
        self.perturb_with(ctx, current, film, |w| perturb_direction(w, theta1, theta2, rng).0)
    }
}
