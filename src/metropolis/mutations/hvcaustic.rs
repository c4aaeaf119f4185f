//! The half-vector caustic perturbation: Veach's caustic perturbation (`caustic`) continued through
//! near-specular glossy vertices held at their half vectors, the light-side mirror of `hvlens` (HSLT's
//! parameterisation, Kaplanyan et al. 2014, §4, with the camera end of the chain left free).
//!
//! | parameter | value | meaning |
//! |---|---|---|
//! | `specular_threshold` (`--specular-threshold`) | 0.1 | a glossy vertex with α below this is held at its half vector; the rest end the chain |
//! | θ1, θ2, angle density | as `caustic` | the turn of the direction leaving x_m |
//!
//! For a path whose camera sees a non-specular x_1 lit through x_2 … x_{m−1}, each Dirac or held, the
//! move turns the direction leaving x_m (the first vertex from x_2 on that is neither, or the emitter)
//! and retraces the chain towards the camera: a Dirac vertex through its lobe, a held vertex in the
//! direction whose half vector in its shading frame is the old one's, until a new y_1, which connects
//! to the camera. A rough ring on a diffuse floor is the case it is for: on camera, floor, ring, light
//! the caustic perturbation can only turn the direction leaving the ring at a fixed ring point, while
//! this one turns the light's emission and lets the ring point slide, as light tracing does.
//!
//! The map (ω_m, h_{m−1} … h_2) → (y_{m−1} … y_1) is block lower triangular in tracing order (h_j
//! depends on y_{j+1}, y_j and y_{j−1}), so, as in `hvlens`, its determinant is the area conversion of
//! the traced vertices times Π dω_h/dω_o at the held ones, and T(y→x)/T(x→y) is the angular density
//! ratio times D(x)/D(y) with D that product.

use super::perturb::{
    angular_density, connect_visible, conversion_product_reversed, film_radius_range, held_jacobian_product,
    is_held, perturb_direction, radians_per_pixel, ray_from, trace_held_chain,
};
use crate::bsdf::TransportMode;
use crate::geometry::Vec3;
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;

/// The half-vector caustic perturbation; `threshold` is the roughness below which a glossy vertex is
/// held (0: Veach's caustic perturbation exactly).
#[derive(Clone, Copy, Debug)]
pub struct HalfVectorCausticPerturbation {
    pub threshold: f32,
}

impl HalfVectorCausticPerturbation {
    /// m, the vertex whose outgoing direction is turned, if the perturbation applies: x_1 non-specular
    /// and connectible to the camera, x_2 … x_{m−1} Dirac or held, and x_m the first vertex after them
    /// that is neither (or the emitter end, possibly a point light), not an environment.
    pub fn applicable(&self, x: &[Vertex]) -> Option<usize> {
        let n = x.len();
        if n < 3 || x[1].delta || !x[1].connectible() || x[1].kind != VertexKind::Surface {
            return None;
        }
        let m = (2..n).find(|&i| !(x[i].delta || is_held(&x[i], self.threshold))).unwrap_or(n - 1);
        (x[m].kind != VertexKind::InfiniteLight).then_some(m)
    }

    /// [θ1, θ2] of a path with turned vertex m: the film offsets of the lens perturbation, carried to
    /// x_m as if the chain were straight (Veach's heuristic).
    pub fn angle_range(scene: &Scene, x: &[Vertex], m: usize) -> (f64, f64) {
        let (r1, r2) = film_radius_range(scene);
        let camera_distance = (x[0].p - x[1].p).length() as f64;
        let chain_length: f64 = (1..m).map(|i| (x[i].p - x[i + 1].p).length() as f64).sum();
        let scale = radians_per_pixel(scene) * camera_distance / chain_length;
        (r1 * scale, r2 * scale)
    }

    /// D(p) of the chain p_1 … p_m: the area conversion from x_m's direction and Π dω_h/dω_o at the
    /// held vertices, both in tracing order (from p_m).
    fn chain_density(&self, scene: &Scene, chain: &[Vertex]) -> f64 {
        conversion_product_reversed(scene, chain) * held_jacobian_product(scene, chain, self.threshold, true)
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
        let x = &current.vertices;
        if x.len() > ctx.max_vertices() {
            return Err(Failure::NotApplicable);
        }
        let m = self.applicable(x).ok_or(Failure::NotApplicable)?;
        let scene = ctx.scene;
        let (theta1, theta2) = Self::angle_range(scene, x, m);
        // The chain in tracing order, from the light side: x_m, x_{m−1}, …, x_1.
        let old: Vec<Vertex> = x[1..=m].iter().rev().copied().collect();
        let ray = ray_from(&x[m], w_new);
        let traced = trace_held_chain(ctx, &old, ray, TransportMode::Importance, false, self.threshold)?;
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
        let forward = angular_density(theta, theta1, theta2) * self.chain_density(scene, &y[1..=m]);
        let backward = angular_density(theta, y_theta1, y_theta2) * self.chain_density(scene, &x[1..=m]);
        if !(forward > 0.0 && forward.is_finite() && backward.is_finite()) {
            return Err(Failure::Failed("zero_density"));
        }
        let state = PathState::new(scene, y).ok_or(Failure::Failed("no_contribution"))?;
        Ok(Proposal { state, t_ratio: backward / forward })
    }
}

impl<'a> Mutation<PathState, PathContext<'a>> for HalfVectorCausticPerturbation {
    fn name(&self) -> &'static str {
        "hvcaustic"
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
        let m = self.applicable(x).ok_or(Failure::NotApplicable)?;
        let (theta1, theta2) = Self::angle_range(ctx.scene, x, m);
        if !(theta1 > 0.0 && theta2 > theta1 && theta2.is_finite()) {
            return Err(Failure::Failed("degenerate_range"));
        }
        let w = x[m].direction_to(&x[m - 1]);
        let (w_new, theta) = perturb_direction(w, theta1, theta2, rng);
        self.perturb_to(ctx, current, w_new, theta)
    }
}
