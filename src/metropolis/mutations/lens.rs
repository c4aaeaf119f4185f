//! Veach's lens perturbation (Veach 1997, §11.4.2; Mitsuba's `mut_lens.cpp`): move the image point of
//! a path by a small film offset, retrace the camera's specular chain x_1 … x_{c−1} through the same
//! Dirac lobes to a new non-specular y_c, and connect y_c to the unchanged rest of the path.
//!
//! | parameter | value | meaning |
//! |---|---|---|
//! | r1 | `perturb::FILM_R1_PIXELS` = 0.1 px | smallest film offset |
//! | r2 | sqrt(`perturb::FILM_R2_AREA_FRACTION` · W · H / π) = sqrt(0.05 W H / π) px | largest offset |
//! | offset density | ∝ 1/r on [r1, r2], uniform angle | symmetric, so it cancels in T(y→x)/T(x→y) |
//!
//! With a pinhole, d film / dω ∝ `camera.pdf_dir`, so T(y→x)/T(x→y) = D(x)/D(y) with
//! D(p) = pdf_dir(p_0→p_1) · Π_{i=1..c} |cos θ_i| / d²(p_{i−1}, p_i) (Dirac convention).
//! It is run as the half-vector lens perturbation (`hvlens`) with no glossy vertex held, which is
//! this move exactly, so the two cannot drift apart.

use super::hvlens::HalfVectorLensPerturbation;
use super::perturb::sample_film_offset;
use crate::geometry::Vec2;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;

/// The lens perturbation (stateless: its parameters are the constants of `perturb`).
#[derive(Clone, Copy, Debug, Default)]
pub struct LensPerturbation;

impl LensPerturbation {
    /// The half-vector lens perturbation holding no glossy vertex is exactly this move: the same
    /// chain end c, the same trace through Dirac lobes, the same density (`hvlens`).
    const AS_HALF_VECTOR_LENS: HalfVectorLensPerturbation = HalfVectorLensPerturbation { threshold: 0.0 };

    /// c, the first non-specular vertex after the camera, if the perturbation applies to `x`: either
    /// the chain ends on a hittable emitter (c = k) or x_c and x_{c+1} can be joined by an edge.
    pub fn applicable(scene: &Scene, x: &[Vertex], hide_emitters: bool) -> Option<usize> {
        Self::AS_HALF_VECTOR_LENS.applicable(scene, x, hide_emitters)
    }

    /// The deterministic part of the move: the path of `current` re-seen through film position
    /// `film`, with T(y→x)/T(x→y). Tests call it to retrace a proposal back to where it came from.
    pub fn perturb_to(
        &self,
        ctx: &mut PathContext,
        current: &PathState,
        film: Vec2,
    ) -> Result<Proposal<PathState>, Failure> {
        Self::AS_HALF_VECTOR_LENS.perturb_to(ctx, current, film)
    }
}

impl<'a> Mutation<PathState, PathContext<'a>> for LensPerturbation {
    fn name(&self) -> &'static str {
        "lens"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        _stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        if Self::applicable(ctx.scene, &current.vertices, ctx.bdpt.hide_emitters).is_none() {
            return Err(Failure::NotApplicable);
        }
        let film = current.film + sample_film_offset(ctx.scene, rng);
        self.perturb_to(ctx, current, film)
    }
}
