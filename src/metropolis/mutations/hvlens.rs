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

use super::perturb::{camera_chain_density, join_camera_chain, primary_ray, ray_from};
use crate::bsdf::TransportMode;
use crate::geometry::{Vec2, Vec3};
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{ScatterClass, Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// The half-vector lens perturbation; `threshold` is the roughness below which a glossy vertex is held.
#[derive(Clone, Copy, Debug)]
pub struct HalfVectorLensPerturbation {
    pub threshold: f32,
}

/// A non-Dirac surface vertex glossy enough to be carried at its half vector.
pub fn is_held(v: &Vertex, threshold: f32) -> bool {
    v.kind == VertexKind::Surface
        && !v.delta
        && matches!(v.class, ScatterClass::Glossy { alpha } if alpha < threshold)
}

/// The relative index η_o/η_i that forms H = ω_i + η ω_o at `v`: 1 for reflection, the BSDF's ratio for
/// transmission, inverted when ω_i arrives from inside (as `manifold::constraint` does).
fn relative_eta(scene: &Scene, v: &Vertex, wi: DVec3, reflect: bool) -> f64 {
    if reflect {
        return 1.0;
    }
    let eta = v.bsdf(scene).map_or(1.0, |b| b.eta() as f64);
    if v.ng.as_dvec3().dot(wi) > 0.0 {
        eta
    } else {
        1.0 / eta
    }
}

/// The unit (generalised) half vector of `v` between ω_i and ω_o, on the side of the shading normal,
/// with dω_h/dω_o; `None` where ω_i = −η ω_o leaves it undefined.
fn half_vector(scene: &Scene, v: &Vertex, wi: Vec3, wo: Vec3) -> Option<(DVec3, f64)> {
    let (wi, wo) = (wi.as_dvec3(), wo.as_dvec3());
    let reflect = v.reflects(wi.as_vec3(), wo.as_vec3());
    let eta = relative_eta(scene, v, wi, reflect);
    let raw = wi + wo * eta;
    let len2 = raw.length_squared();
    if !(len2 > 1e-12 * (1.0 + eta) * (1.0 + eta)) {
        return None;
    }
    let mut h = raw / len2.sqrt();
    if h.dot(v.frame.n.as_dvec3()) < 0.0 {
        h = -h;
    }
    let jacobian = eta * eta * wo.dot(h).abs() / len2;
    Some((h, jacobian))
}

/// The direction leaving `v` whose half vector with `wi` is `h` on the `reflect` side, if there is one.
fn direction_for_half_vector(scene: &Scene, v: &Vertex, wi: Vec3, h: DVec3, reflect: bool) -> Option<Vec3> {
    let wi = wi.as_dvec3();
    let h = if wi.dot(h) < 0.0 { -h } else { h };
    let cos_i = wi.dot(h);
    let wo = if reflect {
        h * (2.0 * cos_i) - wi
    } else {
        let eta = relative_eta(scene, v, wi, false);
        let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
        if sin2_t >= 1.0 {
            return None;
        }
        let cos_t = (1.0 - sin2_t).sqrt();
        -wi / eta + h * (cos_i / eta - cos_t)
    };
    let wo = wo.normalize_or_zero().as_vec3();
    let ng = v.ng;
    let same_side = ng.dot(wi.as_vec3()) * ng.dot(wo) > 0.0;
    (wo != Vec3::ZERO && same_side == reflect && v.reflects(wi.as_vec3(), wo) == reflect).then_some(wo)
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
        let mut density = camera_chain_density(scene, chain);
        for j in 1..chain.len() - 1 {
            if is_held(&chain[j], self.threshold) {
                let wi = chain[j].direction_to(&chain[j - 1]);
                let wo = chain[j].direction_to(&chain[j + 1]);
                density *= half_vector(scene, &chain[j], wi, wo).map_or(0.0, |(_, jac)| jac);
            }
        }
        density
    }

    /// Retraces x_1 … x_c from the primary ray through `film`: returns `[x_0, y_1, …, y_c]`.
    fn trace(
        &self,
        ctx: &mut PathContext,
        x: &[Vertex],
        c: usize,
        film: Vec2,
    ) -> Result<Vec<Vertex>, Failure> {
        let scene = ctx.scene;
        let ends_on_emitter = c == x.len() - 1;
        let mut ray = primary_ray(scene, film)?;
        let mut out = Vec::with_capacity(c + 1);
        out.push(x[0]);
        for j in 1..=c {
            ctx.counters.rays += 1;
            let escapes = j == c && x[c].kind == VertexKind::InfiniteLight;
            let Some(si) = scene.intersect(&ray) else {
                let light = x[c].light.filter(|_| escapes).ok_or(Failure::Failed("miss"))?;
                out.push(Vertex::infinite(scene, light, ray.origin, ray.dir));
                return Ok(out);
            };
            if escapes {
                return Err(Failure::Failed("blocked_environment"));
            }
            let mut v = Vertex::surface(scene, &si, Spectrum::ONE);
            let old = &x[j];
            if j == c {
                if ends_on_emitter && v.light.is_none() {
                    return Err(Failure::Failed("missed_emitter"));
                }
                if !ends_on_emitter && is_held(&v, self.threshold) {
                    return Err(Failure::Failed("chain_structure"));
                }
                out.push(v);
                return Ok(out);
            }
            let reflect = old.reflects(old.direction_to(&x[j - 1]), old.direction_to(&x[j + 1]));
            let wo = if old.delta {
                let wo = v.dirac_direction(scene, si.wi, reflect, TransportMode::Radiance);
                v.delta = true;
                wo.ok_or(Failure::Failed("no_dirac_lobe"))?
            } else {
                if !is_held(&v, self.threshold) {
                    return Err(Failure::Failed("chain_structure"));
                }
                let (h_old, _) =
                    half_vector(scene, old, old.direction_to(&x[j - 1]), old.direction_to(&x[j + 1]))
                        .ok_or(Failure::Failed("degenerate_half_vector"))?;
                let h_local = old.frame.to_local(h_old.as_vec3());
                let h_new = v.frame.to_world(h_local).as_dvec3().normalize_or_zero();
                direction_for_half_vector(scene, &v, si.wi, h_new, reflect)
                    .ok_or(Failure::Failed("no_direction_for_half_vector"))?
            };
            ray = ray_from(&v, wo);
            out.push(v);
        }
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
