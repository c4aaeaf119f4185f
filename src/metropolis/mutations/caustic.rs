//! Veach's caustic perturbation (Veach 1997, §11.4.3; Mitsuba's `mut_caustic.cpp`): for a path whose
//! camera sees a non-specular x_1 lit through a specular chain x_2 … x_{m−1}, turn the direction
//! leaving x_m by a small angle, retrace the chain from x_m to a new y_1 and connect y_1 to the camera.
//!
//! | parameter | value | meaning |
//! |---|---|---|
//! | θ1 | rpp · r1 · \|x_0 − x_1\| / Σ_{i=1}^{m−1} \|x_i − x_{i+1}\| | smallest angle (r1 = `perturb::FILM_R1_PIXELS`) |
//! | θ2 | rpp · r2 · \|x_0 − x_1\| / Σ_{i=1}^{m−1} \|x_i − x_{i+1}\| | largest angle (r2 as the lens perturbation's) |
//! | rpp | horizontal field of view / width | radians per pixel, so the image moves by about r pixels |
//! | angle density | ∝ 1/θ on [θ1, θ2], uniform azimuth | solid angle: 1 / (2π ln(θ2/θ1) θ sin θ) |
//!
//! The range depends on the path, so T(y→x) uses the range computed on y: a θ outside it gives
//! T(y→x) = 0 (a valid proposal that is always rejected). It is run as the half-vector caustic
//! perturbation (`hvcaustic`) with no glossy vertex held, which is this move exactly, so the two
//! cannot drift apart.

use super::hvcaustic::HalfVectorCausticPerturbation;
use crate::geometry::Vec3;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::Vertex;
use crate::sampling::Sampler;

/// The caustic perturbation (stateless).
#[derive(Clone, Copy, Debug, Default)]
pub struct CausticPerturbation;

impl CausticPerturbation {
    /// The half-vector caustic perturbation holding no glossy vertex is exactly this move.
    const AS_HALF_VECTOR_CAUSTIC: HalfVectorCausticPerturbation =
        HalfVectorCausticPerturbation { threshold: 0.0 };

    /// m, the vertex on the light side of the specular chain seen through x_1, if the perturbation
    /// applies: x_1 non-specular and connectible to the camera, x_2 … x_{m−1} specular, and x_m the first
    /// non-specular vertex after them (or the emitter end, possibly a point light), not an environment.
    pub fn applicable(x: &[Vertex]) -> Option<usize> {
        Self::AS_HALF_VECTOR_CAUSTIC.applicable(x)
    }

    /// The deterministic part of the move: the chain of `current` retraced from x_m along `w_new`,
    /// at angle `theta` from the old direction x_m → x_{m−1}, with T(y→x)/T(x→y). Tests call it to
    /// retrace a proposal back to where it came from.
    pub fn perturb_to(
        &self,
        ctx: &mut PathContext,
        current: &PathState,
        w_new: Vec3,
        theta: f64,
    ) -> Result<Proposal<PathState>, Failure> {
        Self::AS_HALF_VECTOR_CAUSTIC.perturb_to(ctx, current, w_new, theta)
    }
}

impl<'a> Mutation<PathState, PathContext<'a>> for CausticPerturbation {
    fn name(&self) -> &'static str {
        "caustic"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let mut as_half_vector = Self::AS_HALF_VECTOR_CAUSTIC;
        as_half_vector.propose(current, ctx, rng, stats)
    }
}
