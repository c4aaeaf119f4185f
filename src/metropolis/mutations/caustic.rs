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
//! T(y→x) = 0 (a valid proposal that is always rejected).

use super::perturb::{
    angular_density, connect_visible, conversion_product_reversed, film_radius_range, first_non_delta,
    perturb_direction, radians_per_pixel, ray_from, trace_specular_chain,
};
use crate::bsdf::TransportMode;
use crate::geometry::Vec3;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;

/// The caustic perturbation (stateless).
#[derive(Clone, Copy, Debug, Default)]
pub struct CausticPerturbation;

impl CausticPerturbation {
    /// m, the vertex on the light side of the specular chain seen through x_1, if the perturbation
    /// applies: x_1 non-specular and connectible to the camera, x_2 … x_{m−1} specular, and x_m the first
    /// non-specular vertex after them (or the emitter end, possibly a point light), not an environment.
    pub fn applicable(x: &[Vertex]) -> Option<usize> {
        let n = x.len();
        if n < 3 || x[1].delta || !x[1].connectible() || x[1].kind != VertexKind::Surface {
            return None;
        }
        let m = first_non_delta(x, 2).unwrap_or(n - 1);
        (x[m].kind != VertexKind::InfiniteLight).then_some(m)
    }

    /// [θ1, θ2] of a path with caustic vertex m.
    pub fn angle_range(scene: &Scene, x: &[Vertex], m: usize) -> (f64, f64) {
        let (r1, r2) = film_radius_range(scene);
        let camera_distance = (x[0].p - x[1].p).length() as f64;
        let chain_length: f64 = (1..m).map(|i| (x[i].p - x[i + 1].p).length() as f64).sum();
        let scale = radians_per_pixel(scene) * camera_distance / chain_length;
        (r1 * scale, r2 * scale)
    }
}

impl CausticPerturbation {
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
        let x = &current.vertices;
        if x.len() > ctx.max_vertices() {
            return Err(Failure::NotApplicable);
        }
        let m = Self::applicable(x).ok_or(Failure::NotApplicable)?;
        let scene = ctx.scene;
        let (theta1, theta2) = Self::angle_range(scene, x, m);
        // The chain in tracing order, from the light side: x_m, x_{m−1}, …, x_1.
        let old: Vec<Vertex> = x[1..=m].iter().rev().copied().collect();
        let ray = ray_from(&x[m], w_new);
        let traced = trace_specular_chain(ctx, &old, ray, TransportMode::Importance, false)?;
        let y1 = traced[traced.len() - 1];
        if !y1.connectible() {
            return Err(Failure::Failed("not_connectible"));
        }
        if scene.camera.film_position(x[0].direction_to(&y1)).is_none() {
            return Err(Failure::Failed("outside_image"));
        }
        if !connect_visible(ctx, &x[0], &y1) {
            return Err(Failure::Failed("occluded"));
        }
        let mut y = Vec::with_capacity(x.len());
        y.push(x[0]);
        y.extend(traced.iter().rev().copied());
        y.extend_from_slice(&x[m..]);
        let (y_theta1, y_theta2) = Self::angle_range(scene, &y, m);
        let forward = angular_density(theta, theta1, theta2) * conversion_product_reversed(scene, &y[1..=m]);
        let backward =
            angular_density(theta, y_theta1, y_theta2) * conversion_product_reversed(scene, &x[1..=m]);
        if !(forward > 0.0 && forward.is_finite()) {
            return Err(Failure::Failed("zero_density"));
        }
        let state = PathState::new(scene, y).ok_or(Failure::Failed("no_contribution"))?;
        Ok(Proposal { state, t_ratio: backward / forward })
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
        _stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let x = &current.vertices;
        if x.len() > ctx.max_vertices() {
            return Err(Failure::NotApplicable);
        }
        let m = Self::applicable(x).ok_or(Failure::NotApplicable)?;
        let (theta1, theta2) = Self::angle_range(ctx.scene, x, m);
        if !(theta1 > 0.0 && theta2 > theta1 && theta2.is_finite()) {
            return Err(Failure::Failed("degenerate_range"));
        }
        let w = x[m].direction_to(&x[m - 1]);
        let (w_new, theta) = perturb_direction(w, theta1, theta2, rng);
        self.perturb_to(ctx, current, w_new, theta)
    }
}
