//! HSLT's half-vector space mutation (Kaplanyan, Hanika and Dachsbacher 2014, Sec. 5–6; digest 2.4–2.7):
//! Möbius-shifted Phong steps of every inner vertex's half vector, sized by roughness and image-space
//! stratification, a Newton walk there with x_0 and x_k fixed, weighed in half-vector measure f_A/|det J|.
//! The walk's ray casts start from the camera or the light end (Sec. 5.1, digest 2.9, `TraceDirection`),
//! and it moves the whole path or a sub-chain between two rough vertices (`subchain`, improved HSLT).

use glam::{DMat2, DVec2, DVec3};

use super::super::chain::{Failure, Mutation, MutationStats, Proposal};
use super::super::path_state::{PathContext, PathState};
use super::subchain::walkable;
pub use super::subchain::{sub_chains, Chain};
use crate::manifold::{
    bandwidth_shares, frame_chart, invert_block, log_dirac_factor, path_constraints, path_etas,
    path_geometry, path_geometry_in_chart, step_sizes, walk_in_chart_counting_rays, walk_many, BlockLu,
    LocalGeometry, StepSizes, WalkError, WalkJob, WalkResult, WalkSettings, WalkStart,
};
use crate::path::{PathView, ScatterClass, Vertex, VertexKind};
use crate::sampling::{Distribution1D, Sampler};
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
    /// Which fixed end the walk's ray casts start from (`--hslt-direction`).
    pub direction: TraceDirection,
    /// Move a stretch x_b … x_c of the path with x_b and x_c held, chosen by `chains` (improved HSLT,
    /// Hanika et al. 2015; digest 2.11), instead of always the whole path (`--hslt-chains`).
    pub sub_chains: bool,
}

/// Which end of the path the Newton walk's corrector casts its rays from (paper Sec. 5.1: HSLT picks
/// "whichever is more convenient" per mutation, with an unpublished criterion; digest 2.9).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TraceDirection {
    /// Always from the camera x_0 (the reference implementation's only choice).
    #[default]
    Camera,
    /// Always from the emitter end x_k.
    Light,
    /// From the end whose adjacent inner vertex is the smoother one (`TraceDirection::start_for`).
    Rule,
}

/// The end a particular walk starts from, once `TraceDirection::Rule` has been decided on a path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceStart {
    Camera,
    Light,
}

impl TraceDirection {
    pub const ALL: [TraceDirection; 3] =
        [TraceDirection::Camera, TraceDirection::Light, TraceDirection::Rule];

    pub fn name(self) -> &'static str {
        match self {
            TraceDirection::Camera => "camera",
            TraceDirection::Light => "light",
            TraceDirection::Rule => "rule",
        }
    }

    pub fn parse(name: &str) -> Result<TraceDirection, String> {
        TraceDirection::ALL
            .into_iter()
            .find(|d| d.name() == name)
            .ok_or_else(|| format!("unknown tracing direction '{name}' (available: camera, light, rule)"))
    }

    /// The end to trace `path` (an applicable path) from. The rule starts from the end whose adjacent
    /// inner vertex has the smaller roughness (diffuse counting as 1), the camera on ties. Why: the
    /// corrector places each vertex with a ray from the already placed previous one, so an error at an
    /// early vertex tilts every later ray while the last vertex is only joined to the fixed end; the
    /// smoother vertex takes the smaller half-vector step (steps scale with α), so its linear prediction
    /// is the more accurate and it makes the better first vertex. On caustic paths (L-glossy-…-diffuse-E)
    /// this traces from the light, as light tracing does. It reads only the path, so it is deterministic.
    /// Measured, it is within noise of `Camera` on jewelry, fig17 and fig15 (docs/mlt.md).
    pub fn start_for(self, path: &[Vertex]) -> TraceStart {
        match self {
            TraceDirection::Camera => TraceStart::Camera,
            TraceDirection::Light => TraceStart::Light,
            TraceDirection::Rule => {
                let roughness = |v: &Vertex| bsdf_step(v, 1.0);
                let n = path.len();
                if roughness(&path[n - 2]) < roughness(&path[1]) {
                    TraceStart::Light
                } else {
                    TraceStart::Camera
                }
            }
        }
    }
}

/// The Newton walk of `path` to `target` (one per inner vertex, camera to light order, coordinates in
/// the chart of `prepared`, which was prepared from `path`), with the corrector's rays cast from the
/// chosen end. From the camera the walk starts from what preparing evaluated (`WalkStart`).
/// From the light it walks the reversed path and reverses the result: every inner vertex's half
/// vector is the same quantity both ways (reflection is symmetric in wi, wo; for refraction
/// H~ = wi + η·wo becomes wo + wi/η = H~/η, the same direction, and frames are per vertex), so the
/// targets, the constraint and its Jacobian (rows and columns reversed blockwise, the same |det J|)
/// are unchanged, and the walk's side checks and endpoint handling are symmetric in the two ends.
pub fn walk_from(
    scene: &Scene,
    path: &[Vertex],
    prepared: &PreparedPath,
    target: &[DVec2],
    start: TraceStart,
    settings: &WalkSettings,
    rays: &mut u64,
) -> Result<WalkResult, WalkError> {
    match start {
        TraceStart::Camera => {
            let job = WalkJob {
                path,
                eta: &prepared.eta,
                target,
                chart: Some(&prepared.chart),
                start: Some(WalkStart { geometry: &prepared.geometry, h: &prepared.h, lu: &prepared.lu }),
            };
            let mut results = walk_many(scene, &[job], settings, std::slice::from_mut(rays));
            results.pop().expect("one result per job")
        }
        TraceStart::Light => {
            let reversed = |v: &[Vertex]| v.iter().rev().copied().collect::<Vec<_>>();
            let eta_rev: Vec<f64> = prepared.eta.iter().rev().copied().collect();
            let target_rev: Vec<DVec2> = target.iter().rev().copied().collect();
            let chart_rev: Vec<DVec3> = prepared.chart.iter().rev().copied().collect();
            let mut result = walk_in_chart_counting_rays(
                scene,
                &reversed(path),
                &eta_rev,
                &target_rev,
                Some(&chart_rev),
                settings,
                rays,
            )?;
            result.path.reverse();
            result.h.reverse();
            Ok(result)
        }
    }
}

/// The walk gives up after this many Newton iterations ([C13]: 15; the shared default 20). A walk that
/// converges does so in 2-3 (rings scene: 2.5 on average, 96% of converged walks within 9), while one
/// that runs long almost never does, and it is the failed walks that cost: each failed iteration
/// traces up to three corrector passes. On rings (128x96, `--integrator hslt --time 20 --seed 1`, run
/// back to back) 20 iterations and `MIN_STEP` 1e-5 made 695 k proposals, 240 k accepted; 10 and 1e-2
/// made 786 k, 269 k accepted (+13%, +12%), and the render 13% more mutations of every kind.
pub const MAX_ITERATIONS: usize = 10;

/// The smallest step fraction the walk traces: each iteration tries 1, 1/2 and 1/4 of the current step
/// (which starts at 1 and doubles after an accepted fraction), so a walk gives up as soon as no
/// fraction of at least a quarter lowers the error. Of the walks that failed with the old limit (1e-2,
/// checked only after a whole iteration failed), most crawled: each accepted step 1/128 or 1/512 of
/// the way lowered the error by that fraction and no more, for up to 10 iterations, a walk that cannot
/// cross an edge of its manifold. On jewelry they were half the forward walks and 84% of the walks'
/// corrector rows (128 rows per failed walk; 98% of walks failed on paths of 11 or more vertices).
/// Measured with `hslt render SCENE -D resx=128 -D resy=96 --integrator hslt+mlt --time 10 --threads 1`
/// (hslt on rings and fig15), µs per HSLT proposal and acceptance, 1e-2 → 1/8 → 1/4: jewelry 36.9,
/// 0.283 → 29.0, 0.279 → 23.2, 0.275; rings 22.4, 0.340 → 19.0, 0.339 → 15.5, 0.332; fig15 27.0,
/// 0.642 → 22.7, 0.639 → 21.2, 0.630. Accepted proposals per second rise 1.5×, 1.4× and 1.2×.
pub const MIN_STEP: f64 = 0.25;

impl Default for HalfVectorParams {
    fn default() -> HalfVectorParams {
        HalfVectorParams {
            step_scale: 1.0,
            stratify: true,
            image_step: 0.02,
            // Per-triangle tangent frames leave residuals of ~1e-4 in h on tessellated meshes: asking
            // for less makes honest walks fail to converge.
            walk: WalkSettings {
                tolerance: 1e-4,
                max_iterations: MAX_ITERATIONS,
                min_step: MIN_STEP,
                // Only the converged path's last segment is tested: intermediate iterates need not
                // see the light, and a pass then casts one ray fewer (k - 1 instead of k).
                visibility_every_pass: false,
                ..WalkSettings::default()
            },
            direction: TraceDirection::Camera,
            sub_chains: false,
        }
    }
}

/// Whether the mutation applies to a path: at least one inner vertex, all of them surface vertices that
/// either scatter through a non-Dirac lobe (perturbed) or are purely specular (Dirac, held at h = 0),
/// at least one glossy non-Dirac one (all-diffuse paths are the bidirectional mutation's, all-specular
/// chains the perturbations'), and an emitter endpoint with a position (an environment endpoint has
/// none to hold fixed).
pub fn applicable(path: &[Vertex]) -> bool {
    let n = path.len();
    if n < 3 || path[0].kind != VertexKind::Camera || path[n - 1].kind == VertexKind::InfiniteLight {
        return false;
    }
    let inner = &path[1..n - 1];
    inner.iter().all(walkable)
        && inner.iter().any(|v| !v.delta && matches!(v.class, ScatterClass::Glossy { .. }))
}

/// A path prepared for proposing from it: its half vectors, log|det J| and per-vertex proposal steps.
#[derive(Clone, Debug)]
pub struct PreparedPath {
    pub eta: Vec<f64>,
    /// h_1 … h_{k-1} in the path's own tangent frames.
    pub h: Vec<DVec2>,
    /// ln |det J|.
    pub log_det: f64,
    /// Σ ln |dω_o/dh⊥| over the Dirac vertices: their h stays 0 and the chain's measure counts their
    /// outgoing direction, not h (`manifold::log_dirac_factor`).
    pub log_dirac: f64,
    /// The Dirac vertices among x_1 … x_{k-1}: held at h = 0, no step, no kernel factor.
    pub held: Vec<bool>,
    pub steps: Vec<StepSizes>,
    /// The frame chart `h` is in: each inner vertex's frame reference from its own normal
    /// (`manifold::frame_chart`). A proposal's walk holds it, and the other path's half vectors and
    /// |det J| are evaluated in it (`in_chart`) for this kernel's density.
    pub chart: Vec<DVec3>,
    /// The path's local geometry in `chart` and its factorised Jacobian J (whose determinant is
    /// `log_det`): the forward walk from this path starts from them (`WalkStart`).
    pub geometry: Vec<LocalGeometry>,
    pub lu: BlockLu,
}

/// A path's half vectors and ln |det J| in another path's frame chart.
#[derive(Clone, Debug)]
pub struct ChartCoordinates {
    pub h: Vec<DVec2>,
    pub log_det: f64,
}

impl PreparedPath {
    /// Σ_j ln q_j(h_j): the log density of this path's proposal kernel at half vectors `h`; `None`
    /// where the kernel cannot reach them (on or outside the rim, or a grazing centre).
    pub fn log_density(&self, h: &[DVec2]) -> Option<f64> {
        let mut sum = 0.0;
        for (((step, centre), target), _) in
            self.steps.iter().zip(&self.h).zip(h).zip(&self.held).filter(|(_, &held)| !held)
        {
            let q = step.proposal(*centre)?.pdf(*target);
            if !(q > 0.0 && q.is_finite()) {
                return None;
            }
            sum += q.ln();
        }
        Some(sum)
    }

    /// Mean step σ over the perturbed inner vertices and both axes.
    pub fn mean_step(&self) -> f64 {
        let free: Vec<&StepSizes> =
            self.steps.iter().zip(&self.held).filter(|(_, &h)| !h).map(|(s, _)| s).collect();
        let total: f64 = free.iter().map(|s| s.sigma.x + s.sigma.y).sum();
        total / (2 * free.len()).max(1) as f64
    }

    /// This path's half vectors and ln |det J| in `chart`: its own when the charts agree (the common
    /// case; they differ only where a vertex crossed the seam of `normal_frame_reference`). |det J| ·
    /// Π_Dirac |dω_o/dh⊥| turns a half-vector kernel into the chain's area measure (digest 2.4; the
    /// Dirac factor as in MEMLT, docs/mlt.md). The Dirac factor needs no evaluation in another chart:
    /// its vertices sit at h = 0, where a frame rotation leaves |dω_o/dh⊥| unchanged.
    pub fn in_chart(&self, path: &[Vertex], chart: &[DVec3]) -> Option<ChartCoordinates> {
        if chart == self.chart.as_slice() {
            return Some(ChartCoordinates { h: self.h.clone(), log_det: self.log_det });
        }
        let constraints = path_constraints(&path_geometry_in_chart(path, Some(chart)), &self.eta).ok()?;
        let log_det = constraints.jacobian.into_factor().ok()?.log_det().ln_abs;
        log_det.is_finite().then_some(ChartCoordinates { h: constraints.h, log_det })
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
        self.prepare_chain(scene, path, Some(film))
    }

    /// `prepare` for the vertices of a chain (`Chain`), ends included. `film` is the path's film
    /// position when the chain starts at the camera, so that moving it moves the image point and the
    /// steps are capped in image space; `None` (a chain held at both ends away from the camera) keeps
    /// the BSDF steps.
    pub fn prepare_chain(
        &self,
        scene: &Scene,
        path: &[Vertex],
        film: Option<glam::Vec2>,
    ) -> Result<PreparedPath, &'static str> {
        let eta = path_etas(scene, path);
        let geometry = path_geometry(path);
        let constraints = path_constraints(&geometry, &eta).map_err(|_| "degenerate")?;
        let lu = constraints.jacobian.into_factor().map_err(|_| "singular")?;
        let log_det = lu.log_det().ln_abs;
        if !log_det.is_finite() {
            return Err("singular");
        }
        let inner = &path[1..path.len() - 1];
        let held: Vec<bool> = inner.iter().map(|v| v.delta).collect();
        let log_dirac = log_dirac_factor(path, &geometry, &eta).ok_or("degenerate")?;
        let bandwidths: Vec<f64> = inner.iter().map(|v| bsdf_step(v, self.params.step_scale)).collect();
        let steps = if let (true, Some(film)) = (self.params.stratify, film) {
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
        let chart = frame_chart(&geometry);
        Ok(PreparedPath { eta, h: constraints.h, log_det, log_dirac, held, steps, chart, geometry, lu })
    }

    /// The chains a proposal from `path` chooses among, with their unnormalised weights: every
    /// `sub_chains` entry, or only the whole path.
    pub fn chains(&self, path: &[Vertex]) -> Vec<(Chain, f64)> {
        if self.params.sub_chains {
            sub_chains(path)
        } else if applicable(path) {
            vec![(Chain { start: 0, end: path.len() - 1 }, 1.0)]
        } else {
            Vec::new()
        }
    }

    /// ln of the probability that a proposal from `path` moves `chain`; `None` if it never does.
    pub fn chain_log_pmf(&self, path: &[Vertex], chain: Chain) -> Option<f64> {
        let chains = self.chains(path);
        let total: f64 = chains.iter().map(|(_, w)| w).sum();
        let weight = chains.iter().find(|(c, _)| *c == chain)?.1;
        let ln = (weight / total).ln();
        ln.is_finite().then_some(ln)
    }

    /// ln T_H(from → to) for a proposal that moved `chain`: the probability of choosing it times
    /// `from`'s proposal kernel at `to`'s half vectors (both paths of the same shapes and endpoints),
    /// for checking the ratio `propose` returns.
    pub fn transition_log_density(
        &self,
        scene: &Scene,
        from: &PathState,
        to: &PathState,
        chain: Chain,
    ) -> Option<f64> {
        let film = |p: &PathState| (chain.start == 0).then_some(p.film);
        let range = chain.start..=chain.end;
        let prepared_from = self.prepare_chain(scene, &from.vertices[range.clone()], film(from)).ok()?;
        let prepared_to = self.prepare_chain(scene, &to.vertices[range.clone()], film(to)).ok()?;
        let h_to = prepared_to.in_chart(&to.vertices[range], &prepared_from.chart)?.h;
        Some(self.chain_log_pmf(&from.vertices, chain)? + prepared_from.log_density(&h_to)?)
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
        let chains = self.chains(x);
        let chain = match chains.as_slice() {
            [] => return Err(Failure::NotApplicable),
            // No draw for a single choice, so whole-path proposals use the random stream as before.
            [(only, _)] => *only,
            _ => {
                let weights: Vec<f64> = chains.iter().map(|(_, w)| *w).collect();
                let pick = Distribution1D::new(&weights).ok_or(Failure::Failed("degenerate"))?;
                chains[pick.sample(rng.next_f64() as f32).0].0
            }
        };
        let log_pmf_x = self.chain_log_pmf(x, chain).ok_or(Failure::Failed("degenerate"))?;
        let range = chain.start..=chain.end;
        if chain.start > 0 || chain.end < x.len() - 1 {
            stats.add_sum("sub_chains", 1.0);
        }
        stats.add_sum("chain_vertices", (chain.end - chain.start - 1) as f64);
        let x_chain = &x[range.clone()];
        // A chain from the camera moves the image point; one held at both ends away from it does not.
        let film_of = |state: &PathState| (chain.start == 0).then_some(state.film);
        let prepared_x = self.prepare_chain(scene, x_chain, film_of(current)).map_err(Failure::Failed)?;
        stats.add_sum("step_size", prepared_x.mean_step());
        let mut targets = Vec::with_capacity(prepared_x.h.len());
        for ((step, centre), &held) in prepared_x.steps.iter().zip(&prepared_x.h).zip(&prepared_x.held) {
            if held {
                // A Dirac vertex keeps its specular constraint exactly (h = 0, not X's rounding).
                targets.push(DVec2::ZERO);
                continue;
            }
            let proposal = step.proposal(*centre).ok_or(Failure::Failed("grazing"))?;
            let u = [rng.next_f64(), rng.next_f64()];
            targets.push(proposal.sample(u).ok_or(Failure::Failed("grazing"))?);
        }
        let start_x = self.params.direction.start_for(x_chain);
        if start_x == TraceStart::Light {
            stats.add_sum("traced_from_light", 1.0);
        }
        let forward = walk_from(
            scene,
            x_chain,
            &prepared_x,
            &targets,
            start_x,
            &self.params.walk,
            &mut ctx.counters.rays,
        )
        .map_err(|e| Failure::Failed(e.reason()))?;
        stats.add_sum("newton_iterations", forward.iterations as f64);
        stats.add_sum("converged_walks", 1.0);
        let mut walked = x.clone();
        walked[range.clone()].copy_from_slice(&forward.path);
        // x_1 moved, so the image point did: a path leaving the film is outside the state space.
        if PathView::whole(&walked).film_position(scene).is_none() {
            return Err(Failure::Failed("outside_image"));
        }
        // The corrector rebuilds vertices from ray hits; which of them scatter through a Dirac lobe is
        // the path's structure, which the walk keeps.
        for (v, old) in walked.iter_mut().zip(x) {
            v.delta = old.delta;
        }
        let state = PathState::new(scene, walked).ok_or(Failure::Failed("zero_contribution"))?;
        let y_chain = &state.vertices[range];
        let prepared_y = self.prepare_chain(scene, y_chain, film_of(&state)).map_err(Failure::Failed)?;
        // Each kernel lives in its own path's frame chart, so each density needs the other path's
        // coordinates in it: T(x→y) = q_X(h^X(Y)) |det J^X(Y)| in area measure, and likewise back.
        let y_in_x = prepared_y.in_chart(y_chain, &prepared_x.chart).ok_or(Failure::Failed("degenerate"))?;
        let x_in_y = prepared_x.in_chart(x_chain, &prepared_y.chart).ok_or(Failure::Failed("degenerate"))?;
        if prepared_y.chart != prepared_x.chart {
            stats.add_sum("chart_switches", 1.0);
        }
        // Reversibility: Y's walk to X's half vectors must come back to X, or the map from half vectors
        // to paths is not locally one-to-one here and the densities below would not describe it.
        // The walk back starts from the end the direction picks for Y, as a proposal from Y would: the
        // kernel lives in half-vector space and the walk only realises the map h -> path, so T(x->y) is
        // q_X(h_Y)|det J_Y| times 1{the walk from X's start reaches Y}, and T(y->x) likewise with Y's
        // start. The forward indicator is 1 by construction and this check makes the backward one 1,
        // so the ratio below is unchanged. A rule that reads anything but the path (or is random)
        // would need its probability evaluated on X and Y in the ratio.
        let back = walk_from(
            scene,
            y_chain,
            &prepared_y,
            &x_in_y.h,
            self.params.direction.start_for(y_chain),
            &self.params.walk,
            &mut ctx.counters.rays,
        )
        .map_err(|_| Failure::Failed("not_reversible"))?;
        if !(relative_mismatch(x_chain, &back.path) <= REVERSIBILITY_TOLERANCE) {
            return Err(Failure::Failed("not_reversible"));
        }
        // Y chooses the same chain with its own probability (the weights read roughness, which a
        // texture may vary); a chain Y never chooses makes the move irreversible.
        let Some(log_pmf_y) = self.chain_log_pmf(&state.vertices, chain) else {
            return Ok(Proposal { state, t_ratio: 0.0 });
        };
        // Both kernels at the half vectors the paths actually have (the walk's achieved h, not the
        // sampled targets), with the area-measure form of the ratio (digest 2.4).
        let forward_density = prepared_x.log_density(&y_in_x.h).ok_or(Failure::Failed("degenerate"))?;
        let Some(backward_density) = prepared_y.log_density(&x_in_y.h) else {
            // Y's kernel cannot propose X: the move cannot be reversed, so it is never accepted.
            return Ok(Proposal { state, t_ratio: 0.0 });
        };
        let log_ratio = log_pmf_y + backward_density + x_in_y.log_det + prepared_x.log_dirac
            - log_pmf_x
            - forward_density
            - y_in_x.log_det
            - prepared_y.log_dirac;
        let t_ratio = log_ratio.exp();
        if !t_ratio.is_finite() {
            return Err(Failure::Failed("degenerate"));
        }
        Ok(Proposal { state, t_ratio })
    }
}
