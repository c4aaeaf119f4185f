//! The half-vector lens perturbation: Veach's lens perturbation (`lens`) continued through
//! near-specular glossy vertices by holding each one's half vector fixed in its shading frame, the
//! parameterisation of HSLT (Kaplanyan et al. 2014, §4) with the far end of the chain left free.
//!
//! | parameter | value | meaning |
//! |---|---|---|
//! | `specular_threshold` (`--specular-threshold`) | 0.1 | a glossy vertex with α below this is held at its half vector; the rest end the chain |
//! | film offset | as `lens` (∝ 1/r on [r1, r2]) | symmetric, so it cancels |
//!
//! The move maps (image point u, local half vectors h_1 … h_{c−1}) to the camera chain y_1 … y_c by
//! tracing: at a held vertex the outgoing direction is the one whose (generalised) half vector with
//! the incoming ray is the held h; a Dirac vertex goes through its lobe as in `lens`; y_c, the first
//! vertex that is neither, connects to the unchanged x_{c+1}. No Newton solve is needed because y_c
//! is free. The Jacobian ∂(u, h_1 … h_{c−1}) / ∂(y_1 … y_c) is block lower triangular (h_j depends
//! on y_{j−1}, y_j, y_{j+1} only), so its determinant is ∂u/∂y_1 times Π ∂h_j/∂y_{j+1}, each a
//! solid-angle factor dω_h/dω_o = η_o² |ω_o·h| / |η_i ω_i + η_o ω_o|² (Walter et al. 2007, eq. 16–17)
//! times |cos θ_{j+1}| / d². The frame's own rotation along the surface enters only the blocks below
//! the diagonal, which do not change the determinant. T(y→x)/T(x→y) is D(x)/D(y) with D that product.

pub use super::perturb::is_held;
use super::perturb::{
    camera_chain_density, held_jacobian_product, join_camera_chain, primary_ray, trace_held_chain,
};
use crate::bsdf::TransportMode;
use crate::geometry::Vec2;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;

/// The half-vector lens perturbation; `threshold` is the roughness below which a glossy vertex is held.
#[derive(Clone, Copy, Debug)]
pub struct HalfVectorLensPerturbation {
    pub threshold: f32,
}

impl HalfVectorLensPerturbation {
    /// c, the first vertex after the camera that is neither Dirac nor held, if the perturbation
    /// applies: the chain ends on a hittable emitter (c = k) or x_c and x_{c+1} can be joined.
    pub fn applicable(&self, scene: &Scene, x: &[Vertex], hide_emitters: bool) -> Option<usize> {
        let n = x.len();
        if n < 2 || (hide_emitters && n == 2) {
            return None;
        }
        let c = (1..n - 1).find(|&i| !(x[i].delta || is_held(&x[i], self.threshold))).unwrap_or(n - 1);
        if c == n - 1 {
            let end = &x[c];
            return (end.light.is_some() && !end.is_delta_light(scene)).then_some(c);
        }
        (x[c].kind == VertexKind::Surface && x[c].connectible() && x[c + 1].connectible()).then_some(c)
    }

    /// D(p) for the camera chain p_0 … p_c: the lens perturbation's density times dω_h/dω_o at every
    /// held vertex.
    fn chain_density(&self, scene: &Scene, chain: &[Vertex]) -> f64 {
        camera_chain_density(scene, chain) * held_jacobian_product(scene, chain, self.threshold, false)
    }

    /// Retraces x_1 … x_c from the primary ray through `film`: returns `[x_0, y_1, …, y_c]`.
    fn trace(
        &self,
        ctx: &mut PathContext,
        x: &[Vertex],
        c: usize,
        film: Vec2,
    ) -> Result<Vec<Vertex>, Failure> {
        let ray = primary_ray(ctx.scene, film)?;
        let ends_on_emitter = c == x.len() - 1;
        let traced =
            trace_held_chain(ctx, &x[..=c], ray, TransportMode::Radiance, ends_on_emitter, self.threshold)?;
        // y_c must be the first vertex that is not held, as x_c is, or y's chain would end elsewhere.
        if !ends_on_emitter && traced.last().is_some_and(|v| is_held(v, self.threshold)) {
            return Err(Failure::Failed("chain_structure"));
        }
        let mut out = Vec::with_capacity(c + 1);
        out.push(x[0]);
        out.extend(traced);
        Ok(out)
    }

    /// The deterministic part of the move: the path of `current` re-seen through film position `film`
    /// with its half vectors held, and T(y→x)/T(x→y). Tests call it to retrace a proposal back.
    pub fn perturb_to(
        &self,
        ctx: &mut PathContext,
        current: &PathState,
        film: Vec2,
    ) -> Result<Proposal<PathState>, Failure> {
        let x = &current.vertices;
        let n = x.len();
        if n > ctx.max_vertices() {
            return Err(Failure::NotApplicable);
        }
        let c = self.applicable(ctx.scene, x, ctx.bdpt.hide_emitters).ok_or(Failure::NotApplicable)?;
        let y = self.trace(ctx, x, c, film)?;
        join_camera_chain(ctx, x, y, c, |scene, chain| self.chain_density(scene, chain))
    }
}

impl<'a> Mutation<PathState, PathContext<'a>> for HalfVectorLensPerturbation {
    fn name(&self) -> &'static str {
        "hvlens"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        _stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        if self.applicable(ctx.scene, &current.vertices, ctx.bdpt.hide_emitters).is_none() {
            return Err(Failure::NotApplicable);
        }
        let film = current.film + super::perturb::sample_film_offset(ctx.scene, rng);
        self.perturb_to(ctx, current, film)
    }
}
