//! HSLT's half-vector space mutation (Kaplanyan, Hanika and Dachsbacher 2014, Sec. 5–6; digest 2.4–2.7):
//! Möbius-shifted Phong steps of every inner vertex's half vector, sized by roughness and image-space
//! stratification, a Newton walk there with x_0 and x_k fixed, weighed in half-vector measure f_A/|det J|.

use glam::{DMat2, DVec2, DVec3};

use super::super::chain::{Failure, Mutation, MutationStats, Proposal};
use super::super::path_state::{PathContext, PathState};
use crate::manifold::{
    bandwidth_shares, invert_block, path_constraints, path_etas, path_geometry, step_sizes,
    walk_counting_rays, LocalGeometry, StepSizes, WalkSettings,
};
use crate::path::{PathView, ScatterClass, Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;

/// How far the walk back from Y may land from X's inner vertices, relative to the shorter segment at
/// each vertex ([C13]'s `HALFVEC_REL_SPATIAL_EPS`): far enough above the walk's own tolerance (~1e-4
/// in h) to accept honest round trips, far below the distance between two distinct solutions.
pub const REVERSIBILITY_TOLERANCE: f64 = 1e-3;

/// The parameters of the half-vector mutation (`MutationSettings` carries them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfVectorParams {
    /// Multiplies a glossy vertex's roughness α into its BSDF step (paper Sec. 6.1).
    pub step_scale: f64,
    /// Cap the steps by image-space stratification (paper Sec. 6.2); off = BSDF steps only.
    pub stratify: bool,
    /// The image-space step as a fraction of min(width, height) in pixels ([C13]: 2%).
    pub image_step: f64,
    pub walk: WalkSettings,
}

impl Default for HalfVectorParams {
    fn default() -> HalfVectorParams {
        HalfVectorParams {
            step_scale: 1.0,
            stratify: true,
            image_step: 0.02,
            // Per-triangle tangent frames leave residuals of ~1e-4 in h on tessellated meshes: asking
            // for less makes honest walks fail to converge.
            walk: WalkSettings { tolerance: 1e-4, ..WalkSettings::default() },
        }
    }
}

/// Whether the mutation applies to a path: at least one inner vertex, all of them smooth, non-Dirac
/// surface vertices, at least one glossy (all-diffuse paths are the bidirectional mutation's), and an
/// emitter endpoint with a position (an environment endpoint has none to hold fixed).
pub fn applicable(path: &[Vertex]) -> bool {
    let n = path.len();
    if n < 3 || path[0].kind != VertexKind::Camera || path[n - 1].kind == VertexKind::InfiniteLight {
        return false;
    }
    let inner = &path[1..n - 1];
    inner.iter().all(|v| v.kind == VertexKind::Surface && v.smooth && !v.delta)
        && inner.iter().any(|v| matches!(v.class, ScatterClass::Glossy { .. }))
}

/// A path prepared for proposing from it: its half vectors, log|det J| and per-vertex proposal steps.
#[derive(Clone, Debug)]
pub struct PreparedPath {
    pub eta: Vec<f64>,
    /// h_1 … h_{k-1} in the path's own tangent frames.
    pub h: Vec<DVec2>,
    /// ln |det J|.
    pub log_det: f64,
    pub steps: Vec<StepSizes>,
}

impl PreparedPath {
    /// Σ_j ln q_j(h_j): the log density of this path's proposal kernel at half vectors `h`; `None`
    /// where the kernel cannot reach them (on or outside the rim, or a grazing centre).
    pub fn log_density(&self, h: &[DVec2]) -> Option<f64> {
        let mut sum = 0.0;
        for ((step, centre), target) in self.steps.iter().zip(&self.h).zip(h) {
            let q = step.proposal(*centre)?.pdf(*target);
            if !(q > 0.0 && q.is_finite()) {
                return None;
            }
            sum += q.ln();
        }
        Some(sum)
    }

    /// Mean step σ over the inner vertices and both axes.
    pub fn mean_step(&self) -> f64 {
        let total: f64 = self.steps.iter().map(|s| s.sigma.x + s.sigma.y).sum();
        total / (2 * self.steps.len()).max(1) as f64
    }
}

/// The BSDF bandwidth step of an inner vertex (paper Sec. 6.1): α·scale for glossy vertices, the whole
/// disk (1) for diffuse ones.
fn bsdf_step(v: &Vertex, scale: f64) -> f64 {
    match v.class {
        ScatterClass::Glossy { alpha } => scale * alpha as f64,
        ScatterClass::Diffuse => 1.0,
        ScatterClass::Specular => 0.0,
    }
}

/// Where a ray from `origin` along `dir` meets the tangent plane of `at`, as an offset in its (tu, tv).
fn tangent_plane_offset(at: &LocalGeometry, origin: DVec3, dir: DVec3) -> DVec2 {
    let normal = at.tu.cross(at.tv);
    let t = (at.p - origin).dot(normal) / dir.dot(normal);
    let d = origin + dir * t - at.p;
    DVec2::new(d.dot(at.tu), d.dot(at.tv))
}

/// x_1's motion per pixel along the film's x and y (central differences of camera rays intersected
/// with x_1's tangent plane, digest 2.7), in x_1's (tu, tv). Non-finite when a ray is parallel to it.
fn pixel_footprint(scene: &Scene, film: glam::Vec2, x1: &LocalGeometry) -> (DVec2, DVec2) {
    let hit = |dx: f32, dy: f32| {
        let ray = scene.camera.generate_ray(film + glam::Vec2::new(dx, dy));
        tangent_plane_offset(x1, ray.origin.as_dvec3(), ray.dir.as_dvec3())
    };
    ((hit(1.0, 0.0) - hit(-1.0, 0.0)) * 0.5, (hit(0.0, 1.0) - hit(0.0, -1.0)) * 0.5)
}

/// The half-vector mutation.
pub struct HalfVectorMutation {
    pub params: HalfVectorParams,
}

impl HalfVectorMutation {
    pub fn new(params: HalfVectorParams) -> HalfVectorMutation {
        HalfVectorMutation { params }
    }

    /// Constraints, LU of J and step sizes of `path` (an applicable path; `film` its film position).
    pub fn prepare(
        &self,
        scene: &Scene,
        path: &[Vertex],
        film: glam::Vec2,
    ) -> Result<PreparedPath, &'static str> {
        let eta = path_etas(scene, path);
        let geometry = path_geometry(path);
        let constraints = path_constraints(&geometry, &eta).map_err(|_| "degenerate")?;
        let lu = constraints.jacobian.factor().map_err(|_| "singular")?;
        let log_det = lu.log_det().ln_abs;
        if !log_det.is_finite() {
            return Err("singular");
        }
        let inner = &path[1..path.len() - 1];
        let bandwidths: Vec<f64> = inner.iter().map(|v| bsdf_step(v, self.params.step_scale)).collect();
        let steps = if self.params.stratify {
            let shares = bandwidth_shares(&bandwidths);
            let (foot_x, foot_y) = pixel_footprint(scene, film, &geometry[1]);
            let pixels = self.params.image_step * scene.film.width.min(scene.film.height) as f64;
            let d = lu.inverse_row(0);
            bandwidths
                .iter()
                .zip(&shares)
                .zip(&d)
                .map(|((&bw, &share), &d_j)| {
                    // R_j = (∂x_1/∂h_j)⁻¹ turns the image-space step into a step of h_j alone; a
                    // singular D_j (h_j does not move the image point) leaves the BSDF step.
                    let r_j = invert_block(d_j).unwrap_or(DMat2::NAN);
                    let scale = pixels * share;
                    step_sizes(bw, r_j * foot_x * scale, r_j * foot_y * scale)
                })
                .collect()
        } else {
            bandwidths.iter().map(|&bw| step_sizes(bw, DVec2::NAN, DVec2::NAN)).collect()
        };
        Ok(PreparedPath { eta, h: constraints.h, log_det, steps })
    }

    /// ln T_H(from → to): `from`'s proposal kernel at `to`'s half vectors (both applicable paths of the
    /// same shapes and endpoints), for checking the ratio `propose` returns.
    pub fn transition_log_density(&self, scene: &Scene, from: &PathState, to: &PathState) -> Option<f64> {
        let prepared_from = self.prepare(scene, &from.vertices, from.film).ok()?;
        let prepared_to = self.prepare(scene, &to.vertices, to.film).ok()?;
        prepared_from.log_density(&prepared_to.h)
    }
}

/// Largest distance between corresponding inner vertices, relative to the shorter segment at each
/// (what the reversibility check compares with `REVERSIBILITY_TOLERANCE`).
pub fn relative_mismatch(a: &[Vertex], b: &[Vertex]) -> f64 {
    (1..a.len() - 1)
        .map(|i| {
            let seg = (a[i].p - a[i - 1].p).length().min((a[i + 1].p - a[i].p).length()) as f64;
            (a[i].p - b[i].p).length() as f64 / seg
        })
        .fold(0.0, f64::max)
}

impl<'a> Mutation<PathState, PathContext<'a>> for HalfVectorMutation {
    fn name(&self) -> &'static str {
        "hslt"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let scene = ctx.scene;
        let x = &current.vertices;
        if !applicable(x) {
            return Err(Failure::NotApplicable);
        }
        let prepared_x = self.prepare(scene, x, current.film).map_err(Failure::Failed)?;
        stats.add_sum("step_size", prepared_x.mean_step());
        let mut targets = Vec::with_capacity(prepared_x.h.len());
        for (step, centre) in prepared_x.steps.iter().zip(&prepared_x.h) {
            let proposal = step.proposal(*centre).ok_or(Failure::Failed("grazing"))?;
            let u = [rng.next_f64(), rng.next_f64()];
            targets.push(proposal.sample(u).ok_or(Failure::Failed("grazing"))?);
        }
        let forward = walk_counting_rays(
            scene,
            x,
            &prepared_x.eta,
            &targets,
            &self.params.walk,
            &mut ctx.counters.rays,
        )
        .map_err(|e| Failure::Failed(e.reason()))?;
        stats.add_sum("newton_iterations", forward.iterations as f64);
        stats.add_sum("converged_walks", 1.0);
        // x_1 moved, so the image point did: a path leaving the film is outside the state space.
        if PathView::whole(&forward.path).film_position(scene).is_none() {
            return Err(Failure::Failed("outside_image"));
        }
        let state = PathState::new(scene, forward.path).ok_or(Failure::Failed("zero_contribution"))?;
        let prepared_y = self.prepare(scene, &state.vertices, state.film).map_err(Failure::Failed)?;
        // Reversibility: Y's walk to X's half vectors must come back to X, or the map from half vectors
        // to paths is not locally one-to-one here and the densities below would not describe it.
        let back = walk_counting_rays(
            scene,
            &state.vertices,
            &prepared_y.eta,
            &prepared_x.h,
            &self.params.walk,
            &mut ctx.counters.rays,
        )
        .map_err(|_| Failure::Failed("not_reversible"))?;
        if !(relative_mismatch(x, &back.path) <= REVERSIBILITY_TOLERANCE) {
            return Err(Failure::Failed("not_reversible"));
        }
        // Both kernels at the half vectors the paths actually have (the walk's achieved h, not the
        // sampled targets), with the area-measure form of the ratio (digest 2.4).
        let forward_density = prepared_x.log_density(&prepared_y.h).ok_or(Failure::Failed("degenerate"))?;
        let Some(backward_density) = prepared_y.log_density(&prepared_x.h) else {
            // Y's kernel cannot propose X: the move cannot be reversed, so it is never accepted.
            return Ok(Proposal { state, t_ratio: 0.0 });
        };
        let log_ratio = backward_density + prepared_x.log_det - forward_density - prepared_y.log_det;
        let t_ratio = log_ratio.exp();
        if !t_ratio.is_finite() {
            return Err(Failure::Failed("degenerate"));
        }
        Ok(Proposal { state, t_ratio })
    }
}
