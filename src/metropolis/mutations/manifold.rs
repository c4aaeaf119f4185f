//! The manifold perturbation of manifold exploration MLT (Jakob and Marschner 2012, Sec. 5), started at
//! the sensor: move the film position, trace the camera-side chain of specular vertices keeping their
//! half vectors, then walk the next specular chain with the Newton solver so it still joins the fixed
//! vertex beyond it. Glossy vertices below a roughness threshold count as specular (the behaviour the
//! HSLT paper criticises, kept so the comparison is faithful).
//!
//! | parameter | meaning | default |
//! |---|---|---|
//! | `lambda` (`--lambda`) | perturbation size λ: the film offset is Gaussian with σ = √(W·H / 2π) / λ pixels, so its peak density is λ² times that of a uniform film position (Mitsuba's λ² · p_ω at the sensor) | 50 |
//! | `specular_threshold` (`--specular-threshold`) | a glossy vertex with roughness α below this is held at its half vector like a specular one | 0.1 |
//!
//! Measure. Vertices held at their half vector are coordinates h⊥ rather than positions; the film
//! offset is the only free coordinate, so the proposal density in the chain's measure (area for
//! non-Dirac vertices, solid angle with the delta removed after a Dirac vertex) is the film density
//! times |det N| · Π_Dirac |dω_o/dh⊥|, with N = ∂(ω_0, h_held)/∂(moved vertices). N is block
//! triangular: |det N| = conv(x_0→x_1) · Π_{i<b} |det C_i| · |det J_chain|, where C_i = ∂h_i/∂x_{i+1} on
//! the traced chain and J_chain the walked chain's constraint Jacobian (both ends fixed). The film
//! kernel is symmetric and d film / dω ∝ the camera's `pdf_dir`, so
//! T(y→x) / T(x→y) = Q(x) / Q(y), Q = pdf_dir · |det N| · Π_Dirac |dω_o/dh⊥|.

use glam::{DVec2, DVec3};

use crate::geometry::{Ray, Vec2, Vec3};
use crate::manifold::{
    half_vector, half_vector_constraint, log_dirac_factor, path_constraints, path_etas, path_geometry,
    scatter_with_half_vector, walk_counting_rays, LocalGeometry, WalkSettings,
};
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{visible, ScatterClass, Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// The walked chain must come back to the old vertices within this fraction of the adjacent segment
/// length (digest 2.5 step 5; Mitsuba's ShadowEpsilon in f32): otherwise the map from the film offset
/// to paths is not locally one-to-one there and detailed balance would break silently.
const REVERSIBILITY_TOLERANCE: f64 = 1e-3;

pub struct ManifoldPerturbation {
    lambda: f64,
    specular_threshold: f32,
    walk: WalkSettings,
}

impl ManifoldPerturbation {
    pub fn new(lambda: f64, specular_threshold: f32) -> ManifoldPerturbation {
        ManifoldPerturbation {
            lambda,
            specular_threshold,
            walk: WalkSettings { relative_tolerance: 1.0, ..WalkSettings::default() },
        }
    }

    /// Held at its half vector by the perturbation (a Dirac vertex, or glossy below the threshold).
    fn held(&self, v: &Vertex) -> bool {
        v.delta || matches!(v.class, ScatterClass::Glossy { alpha } if alpha < self.specular_threshold)
    }
}

/// Where the perturbation acts on a path: x_1 … x_{b−1} held (traced from the camera), x_b free,
/// x_{b+1} … x_{c−1} held (walked), x_c … x_k kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Structure {
    b: usize,
    c: usize,
}

fn transmits(path: &[Vertex], i: usize) -> bool {
    let ng = path[i].ng;
    ng.dot(path[i - 1].p - path[i].p) * ng.dot(path[i + 1].p - path[i].p) < 0.0
}

fn dvec(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

impl ManifoldPerturbation {
    fn structure(&self, path: &[Vertex]) -> Option<Structure> {
        let k = path.len().checked_sub(1)?;
        if k < 2 {
            return None;
        }
        let b = (1..k).find(|&i| !self.held(&path[i]))?;
        let c = (b + 1..=k).find(|&i| i == k || !self.held(&path[i]))?;
        let surfaces = path[1..c].iter().all(|v| v.kind == VertexKind::Surface);
        let free_ok = path[b].smooth && !path[b].delta;
        let end_ok = path[c].kind != VertexKind::InfiniteLight;
        // A direct reconnection needs both ends to be connectible.
        let link_ok = c > b + 1 || path[c].connectible();
        (surfaces && free_ok && end_ok && link_ok).then_some(Structure { b, c })
    }

    /// ln Q of a path with this structure (module docs); `None` where a factor vanishes or is not
    /// finite (a degenerate frame, a singular chain), which the caller rejects.
    fn log_q(&self, scene: &Scene, path: &[Vertex], eta: &[f64], s: Structure) -> Option<f64> {
        let Structure { b, c } = s;
        let g = path_geometry(&path[..=c]);
        let dir0 = path[0].direction_to(&path[1]);
        let mut lq = (scene.camera.pdf_dir(dir0) as f64).ln();
        lq += (path[0].convert_density(1.0, &path[1], scene) as f64).ln();
        for i in 1..b {
            let vc = half_vector_constraint(&g[i - 1], &g[i], &g[i + 1], eta[i]).ok()?;
            lq += vc.c.determinant().abs().ln();
        }
        if c > b + 1 {
            let constraints = path_constraints(&g[b..=c], &eta[b..=c]).ok()?;
            lq += constraints.jacobian.factor().ok()?.log_det().ln_abs;
        }
        lq += log_dirac_factor(&path[..=c], &g, &eta[..=c])?;
        lq.is_finite().then_some(lq)
    }
}

fn gaussian_pair(rng: &mut Sampler) -> (f64, f64) {
    let r = (-2.0 * (1.0 - rng.next_f64()).ln()).sqrt();
    let phi = std::f64::consts::TAU * rng.next_f64();
    (r * phi.cos(), r * phi.sin())
}

impl Mutation<PathState, PathContext<'_>> for ManifoldPerturbation {
    fn name(&self) -> &'static str {
        "manifold"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'_>,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let scene = ctx.scene;
        let x = &current.vertices;
        let s = self.structure(x).ok_or(Failure::NotApplicable)?;
        let Structure { b, c } = s;
        let eta = path_etas(scene, x);
        let gx = path_geometry(&x[..=c]);
        // The half vectors every held vertex keeps (exactly zero at Dirac vertices, so rounding in the
        // stored path cannot drift them).
        let mut held_h = vec![DVec2::ZERO; c];
        for i in (1..c).filter(|&i| i != b && !x[i].delta) {
            held_h[i] = half_vector(&gx[i - 1], &gx[i], &gx[i + 1], eta[i])
                .map_err(|_| Failure::Failed("degenerate"))?;
        }
        let log_q_x = self.log_q(scene, x, &eta, s).ok_or(Failure::Failed("degenerate"))?;

        let (w, h) = (scene.film.width as f64, scene.film.height as f64);
        let sigma = (w * h / std::f64::consts::TAU).sqrt() / self.lambda;
        let (gx_off, gy_off) = gaussian_pair(rng);
        let film =
            Vec2::new(current.film.x + (sigma * gx_off) as f32, current.film.y + (sigma * gy_off) as f32);
        if !(film.x >= 0.0 && film.y >= 0.0 && film.x < w as f32 && film.y < h as f32) {
            return Err(Failure::Failed("outside_image"));
        }
        stats.add_sum("film_offset_px", (sigma * gx_off).hypot(sigma * gy_off));

        // Camera side: x_1 … x_{b−1} keep their half vectors, x_b is wherever the chain lands.
        let mut y: Vec<Vertex> = Vec::with_capacity(x.len());
        y.push(x[0]);
        let mut ray = scene.camera.generate_ray(film);
        for i in 1..=b {
            ctx.counters.rays += 1;
            let si = scene.intersect(&ray).ok_or(Failure::Failed("missed"))?;
            let mut v = Vertex::surface(scene, &si, Spectrum::ONE);
            if i == b {
                if self.held(&v) || !v.smooth {
                    return Err(Failure::Failed("structure_changed"));
                }
                y.push(v);
                break;
            }
            if si.shape != x[i].shape {
                return Err(Failure::Failed("other_shape"));
            }
            v.delta = x[i].delta;
            let g = LocalGeometry::from_vertex(&v);
            let wi = -dvec(ray.dir);
            let wo = scatter_with_half_vector(&g, wi, held_h[i], eta[i], transmits(x, i))
                .ok_or(Failure::Failed("no_direction"))?
                .as_vec3();
            ray = Ray::leaving(v.p, wo, v.eps);
            y.push(v);
        }

        if c == b + 1 {
            ctx.counters.rays += 1;
            ctx.counters.shadow_rays += 1;
            if !y[b].connectible() || !visible(scene, &y[b], &x[c]) {
                return Err(Failure::Failed("occluded"));
            }
        } else {
            // The walked chain, from the moved x_b to the fixed x_c, then back to the old x_b.
            let mut sub: Vec<Vertex> = Vec::with_capacity(c - b + 1);
            sub.push(y[b]);
            sub.extend_from_slice(&x[b + 1..=c]);
            let sub_eta = &eta[b..=c];
            let targets = &held_h[b + 1..c];
            let rays = &mut ctx.counters.rays;
            let forward = walk_counting_rays(scene, &sub, sub_eta, targets, &self.walk, rays)
                .map_err(|e| Failure::Failed(e.reason()))?;
            stats.add_sum("newton_iterations", forward.iterations as f64);
            let mut back_start = forward.path.clone();
            back_start[0] = x[b];
            let back = walk_counting_rays(scene, &back_start, sub_eta, targets, &self.walk, rays)
                .map_err(|_| Failure::Failed("not_reversible"))?;
            for (j, i) in (b + 1..c).enumerate() {
                let scale = (x[i].p - x[i - 1].p).length().min((x[i + 1].p - x[i].p).length()) as f64;
                let miss = (back.path[j + 1].p - x[i].p).length() as f64;
                if !(miss <= REVERSIBILITY_TOLERANCE * scale) {
                    return Err(Failure::Failed("not_reversible"));
                }
            }
            for (j, i) in (b + 1..c).enumerate() {
                let mut v = forward.path[j + 1];
                v.delta = x[i].delta;
                y.push(v);
            }
        }
        y.extend_from_slice(&x[c..]);
        let log_q_y = self.log_q(scene, &y, &eta, s).ok_or(Failure::Failed("degenerate"))?;
        let state = PathState::new(scene, y).ok_or(Failure::Failed("zero_contribution"))?;
        let t_ratio = (log_q_x - log_q_y).exp();
        Ok(Proposal { state, t_ratio })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Frame;
    use crate::scene::SurfaceDerivatives;

    fn vertex(class: ScatterClass, delta: bool) -> Vertex {
        let d = SurfaceDerivatives {
            dpdu: Vec3::X,
            dpdv: Vec3::Y,
            dndu: Vec3::ZERO,
            dndv: Vec3::ZERO,
            from_uv: true,
        };
        Vertex {
            kind: VertexKind::Surface,
            p: Vec3::ZERO,
            ng: Vec3::Z,
            frame: Frame::from_normal(Vec3::Z),
            uv: Vec2::ZERO,
            derivatives: d,
            shape: 0,
            prim: 0,
            bary: Vec2::ZERO,
            light: None,
            class,
            delta,
            smooth: !delta,
            pdf_from_camera: 0.0,
            pdf_from_light: 0.0,
            beta: Spectrum::ONE,
            eps: 1e-4,
        }
    }

    #[test]
    fn structure_follows_the_roughness_threshold() {
        let m = ManifoldPerturbation::new(50.0, 0.1);
        let mut camera = vertex(ScatterClass::Diffuse, false);
        camera.kind = VertexKind::Camera;
        let mut light = vertex(ScatterClass::Diffuse, false);
        light.kind = VertexKind::Light;
        light.light = Some(0);
        let diffuse = vertex(ScatterClass::Diffuse, false);
        let sharp = vertex(ScatterClass::Glossy { alpha: 0.05 }, false);
        let rough = vertex(ScatterClass::Glossy { alpha: 0.3 }, false);
        let mirror = vertex(ScatterClass::Specular, true);
        // E D S L: the floor is free, the ring (α = 0.05) is walked to the light.
        assert_eq!(m.structure(&[camera, diffuse, sharp, light]), Some(Structure { b: 1, c: 3 }));
        // E S D R L: traced through the mirror, then reconnected directly to the rough vertex.
        assert_eq!(m.structure(&[camera, mirror, diffuse, rough, light]), Some(Structure { b: 2, c: 3 }));
        // E S L: nothing free before the emitter (the lens perturbation's case).
        assert_eq!(m.structure(&[camera, mirror, light]), None);
        // A lower threshold makes the ring free.
        let m = ManifoldPerturbation::new(50.0, 0.01);
        assert_eq!(m.structure(&[camera, diffuse, sharp, light]), Some(Structure { b: 1, c: 2 }));
    }
}
