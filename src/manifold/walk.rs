//! The Newton predictor–corrector walk on the constraint manifold (HSLT, Kaplanyan et al. 2014, Sec. 5.1;
//! Jakob and Marschner 2012 for the specular case): move the inner vertices of a path with fixed ends
//! until their half vectors reach given targets (zero at specular vertices for MEMLT, any for HSLT).
//! Walks are resumable states advanced one corrector row at a time, so `walk_many` can put the rays of
//! many walks in flight into one batched query (issue #7); `walk` is `walk_many` with one job.

use glam::{DVec2, DVec3};

use super::blocktri::BlockLu;
use super::constraint::{
    path_constraints, path_geometry_in_chart, path_geometry_in_chart_into, path_half_vectors,
    path_half_vectors_into, ConstraintError, LocalGeometry,
};
use super::corrector::{CorrectorPass, RayBatch};
use crate::accel::RayQuery;
use crate::path::Vertex;
use crate::scene::Scene;

/// Constants of the walk (digest 2.5 lists what open implementations use).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkSettings {
    pub max_iterations: usize,
    /// Converged when every |h_i − target_i| is below `min(tolerance, relative_tolerance · initial
    /// error)`, but never asked below `precision_floor` (vertices are stored in f32).
    pub tolerance: f64,
    pub relative_tolerance: f64,
    pub precision_floor: f64,
    /// The smallest step fraction a corrector pass traces: the walk gives up when the next candidate
    /// would be smaller, whether the last step was refused or accepted. Accepting ever smaller steps
    /// is how a walk crawls towards an edge of the manifold it cannot cross (or a target it cannot
    /// reach), lowering its error by about the fraction each time and never converging.
    pub min_step: f64,
    /// Cast each corrector row's rays (one per candidate step size, and per walk in flight for
    /// `walk_many`) as one batched query; false casts them one at a time (`hslt bench hslt` measures
    /// both).
    pub batch_rays: bool,
    /// Trace the three candidate step sizes of an iteration (1, ½, ¼ of the current step) in one pass,
    /// so each row's query holds three rays; false (the default) traces the next only when the previous
    /// one failed. Both reach the same iterates. One by one casts 35 rays per HSLT proposal on jewelry
    /// instead of 62 and runs 1.17× faster there, 1.46× on the glossy caustic (`hslt bench hslt`), now
    /// that a one-ray query takes Embree's single-ray kernel rather than a packet with one live lane.
    pub candidates_at_once: bool,
    /// Test every corrector pass's last segment to the fixed end x_k with a ray (a blocked candidate
    /// is refused like a missed one); false tests only the path the walk converges to, with one
    /// batched query after the walks (`WalkError::Occluded`). The inner segments need no test either
    /// way: each inner vertex is the first hit of the ray that placed it.
    pub visibility_every_pass: bool,
}

/// Candidate step fractions per Newton iteration: the step, its half and its quarter (digest 2.5's
/// halving); when all fail the step shrinks by 1/8 for the next iteration.
const CANDIDATES: usize = 3;

impl Default for WalkSettings {
    fn default() -> Self {
        WalkSettings {
            max_iterations: 20,
            tolerance: 1e-5,
            relative_tolerance: 1e-3,
            precision_floor: 2e-6,
            min_step: 1e-5,
            batch_rays: true,
            candidates_at_once: false,
            visibility_every_pass: true,
        }
    }
}

/// Why a walk failed. No variant carries a partially converged path: callers must reject.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum WalkError {
    #[error("the constraint Jacobian is singular at block row {row}")]
    Singular { row: usize },
    #[error(transparent)]
    Constraint(#[from] ConstraintError),
    #[error("did not converge within the iteration or step-size budget")]
    DidNotConverge,
    #[error("the converged path's last segment is blocked")]
    Occluded,
}

impl WalkError {
    /// The short name mutations count this failure under in their statistics.
    pub fn reason(self) -> &'static str {
        match self {
            WalkError::Singular { .. } => "singular",
            WalkError::Constraint(_) => "degenerate",
            WalkError::DidNotConverge => "did_not_converge",
            WalkError::Occluded => "occluded",
        }
    }
}

/// A converged path with its achieved half vectors and the error after each accepted iteration.
#[derive(Clone, Debug)]
pub struct WalkResult {
    pub path: Vec<Vertex>,
    pub h: Vec<DVec2>,
    pub errors: Vec<f64>,
    pub iterations: usize,
}

fn max_error(h: &[DVec2], target: &[DVec2]) -> f64 {
    h.iter().zip(target).map(|(a, b)| (*a - *b).length()).fold(0.0, f64::max)
}

/// One walk for `walk_many`: a start path (x_0 and x_k stay fixed), the BSDF index ratio of each
/// vertex (see `path_etas`) and one target half vector per inner vertex. `chart`, when given, is the
/// frame reference per inner vertex the half vectors (targets and iterates) are coordinates in, held
/// for the whole walk (`frame_chart`); `None` builds each iterate's frames from its own normals.
#[derive(Clone, Copy, Debug)]
pub struct WalkJob<'a> {
    pub path: &'a [Vertex],
    pub eta: &'a [f64],
    pub target: &'a [DVec2],
    pub chart: Option<&'a [DVec3]>,
    /// What the caller has already evaluated at `path` in this chart, or `None`.
    pub start: Option<WalkStart<'a>>,
}

/// The start path's local geometry, half vectors and factorised Jacobian, evaluated in the walk's
/// chart exactly as the walk would evaluate them (`path_geometry_in_chart`, `path_constraints`). The
/// half-vector mutation has them from preparing its kernel, so the walk's first Newton step reuses
/// them instead of evaluating the same constraints twice; the iterates are the same bit for bit.
#[derive(Clone, Copy, Debug)]
pub struct WalkStart<'a> {
    pub geometry: &'a [LocalGeometry],
    pub h: &'a [DVec2],
    pub lu: &'a BlockLu,
}

/// Moves the inner vertices of `path` (x_0 and x_k fixed) until their half vectors equal `target`.
/// `eta[i]` is the BSDF index ratio at vertex i (see `path_etas`).
pub fn walk(
    scene: &Scene,
    path: &[Vertex],
    eta: &[f64],
    target: &[DVec2],
    settings: &WalkSettings,
) -> Result<WalkResult, WalkError> {
    walk_counting_rays(scene, path, eta, target, settings, &mut 0)
}

/// `walk`, adding the rays its corrector casts to `rays` (whether it converges or not), so mutations
/// can report their cost in the render's ray counters.
pub fn walk_counting_rays(
    scene: &Scene,
    path: &[Vertex],
    eta: &[f64],
    target: &[DVec2],
    settings: &WalkSettings,
    rays: &mut u64,
) -> Result<WalkResult, WalkError> {
    walk_in_chart_counting_rays(scene, path, eta, target, None, settings, rays)
}

/// `walk_counting_rays` with the half vectors in `chart` (see `WalkJob`).
pub fn walk_in_chart_counting_rays(
    scene: &Scene,
    path: &[Vertex],
    eta: &[f64],
    target: &[DVec2],
    chart: Option<&[DVec3]>,
    settings: &WalkSettings,
    rays: &mut u64,
) -> Result<WalkResult, WalkError> {
    let job = WalkJob { path, eta, target, chart, start: None };
    let mut results = walk_many(scene, &[job], settings, std::slice::from_mut(rays));
    results.pop().expect("one result per job")
}

thread_local! {
    /// The corrector's ray and hit buffers, kept between walks: a mutation walks twice per proposal,
    /// and fresh buffers cost an allocation per bucket and walk.
    static RAY_BATCH: std::cell::Cell<RayBatch> = std::cell::Cell::new(RayBatch::default());
}

/// Runs all `jobs` together: each round, every unfinished walk contributes the rays of its current
/// corrector row, and they are cast as one batch (Embree packets), so walks in flight share packets.
/// Each walk runs the same steps as alone, so its result is `walk`'s bit for bit unless one of its rays
/// hits two triangles at the same distance, a tie Embree breaks by traversal order, which depends on
/// the packet's other rays (about 1 walk in 5000 at 64 in flight on jewelry; docs/mlt-sessions.md).
/// `rays[j]` gains the rays job j cast.
pub fn walk_many(
    scene: &Scene,
    jobs: &[WalkJob],
    settings: &WalkSettings,
    rays: &mut [u64],
) -> Vec<Result<WalkResult, WalkError>> {
    walk_many_through(scene, scene.accel(), jobs, settings, rays)
}

/// `walk_many` with the ray queries answered by `accel` (the scene's own backend, or a wrapper around
/// it that records or times the queries); hits are resolved against `scene`.
pub fn walk_many_through(
    scene: &Scene,
    accel: &dyn RayQuery,
    jobs: &[WalkJob],
    settings: &WalkSettings,
    rays: &mut [u64],
) -> Vec<Result<WalkResult, WalkError>> {
    assert_eq!(rays.len(), jobs.len(), "one ray counter per job");
    let mut results: Vec<Option<Result<WalkResult, WalkError>>> = jobs.iter().map(|_| None).collect();
    let mut live: Vec<(usize, WalkState)> = Vec::with_capacity(jobs.len());
    for (j, job) in jobs.iter().enumerate() {
        let mut state = match WalkState::start(job, settings) {
            Ok(state) => state,
            Err(e) => {
                results[j] = Some(Err(e));
                continue;
            }
        };
        match state.advance(job, settings) {
            Some(done) => results[j] = Some(done),
            None => live.push((j, state)),
        }
    }
    let mut batch = RAY_BATCH.take();
    let mut slots = Vec::with_capacity(live.len());
    while !live.is_empty() {
        batch.clear();
        slots.clear();
        for (j, state) in &mut live {
            let slot = state.pass.emit(&state.current, &mut batch);
            rays[*j] += slot.len as u64;
            slots.push(slot);
        }
        batch.cast(accel, settings.batch_rays);
        let mut slot = slots.iter();
        live.retain_mut(|(j, state)| {
            state.pass.absorb(scene, &state.current, &batch, slot.next().expect("one slot per live walk"));
            match state.advance(&jobs[*j], settings) {
                Some(done) => {
                    results[*j] = Some(done);
                    false
                }
                None => true,
            }
        });
    }
    RAY_BATCH.set(batch);
    let mut results: Vec<Result<WalkResult, WalkError>> =
        results.into_iter().map(|r| r.expect("every job finishes")).collect();
    if !settings.visibility_every_pass {
        test_last_segments(accel, settings, &mut results, rays);
    }
    results
}

/// Refuses the converged walks whose last segment to the fixed end is blocked, with one query.
fn test_last_segments(
    accel: &dyn RayQuery,
    settings: &WalkSettings,
    results: &mut [Result<WalkResult, WalkError>],
    rays: &mut [u64],
) {
    let mut segments = Vec::new();
    let mut owners = Vec::new();
    for (j, result) in results.iter_mut().enumerate() {
        let Ok(walk) = result else { continue };
        let (near, end) = (&walk.path[walk.path.len() - 2], &walk.path[walk.path.len() - 1]);
        match Scene::shadow_segment(near.p, near.offset(), end.p, end.offset()) {
            Some(ray) => {
                segments.push(ray);
                owners.push(j);
                rays[j] += 1;
            }
            None => *result = Err(WalkError::Occluded),
        }
    }
    let mut blocked = vec![false; segments.len()];
    if settings.batch_rays {
        accel.occluded_batch(&segments, &mut blocked);
    } else {
        for (ray, b) in segments.iter().zip(blocked.iter_mut()) {
            *b = accel.occluded(ray);
        }
    }
    for (&j, &b) in owners.iter().zip(&blocked) {
        if b {
            results[j] = Err(WalkError::Occluded);
        }
    }
}

/// A walk between two ray queries: the Newton iterate, its half vectors and the corrector pass in flight.
struct WalkState {
    current: Vec<Vertex>,
    /// The iterate's half vectors; the Jacobian is evaluated only where a Newton step is taken from it
    /// (not at rejected candidates, nor at the converged end).
    h: Vec<DVec2>,
    error: f64,
    tolerance: f64,
    errors: Vec<f64>,
    step: f64,
    iteration: usize,
    /// The first candidate (0 = the full step) the pass in flight traces.
    candidate: usize,
    /// This iteration's Newton direction, and the geometry of `current` it was computed at.
    dx: Vec<DVec2>,
    /// Whether `dx` is the Newton direction at `current`: after an iteration whose candidates all
    /// failed the iterate has not moved, and the next iteration traces a smaller fraction of it.
    dx_current: bool,
    geometry: Vec<LocalGeometry>,
    /// The pass of iteration `iteration`, or an empty one before the first.
    pass: CorrectorPass,
    /// A traced candidate's geometry and half vectors while it is judged; swapped with `geometry`
    /// and `h` when it is taken, so judging allocates nothing.
    candidate_geometry: Vec<LocalGeometry>,
    candidate_h: Vec<DVec2>,
}

impl WalkState {
    fn start(job: &WalkJob, settings: &WalkSettings) -> Result<WalkState, WalkError> {
        let (path, target) = (job.path, job.target);
        assert!(path.len() >= 3 && target.len() == path.len() - 2, "one target per inner vertex");
        let (geometry, h) = match job.start {
            Some(start) => {
                debug_assert_eq!(start.geometry.len(), path.len(), "start geometry of another path");
                (start.geometry.to_vec(), start.h.to_vec())
            }
            None => {
                let geometry = path_geometry_in_chart(path, job.chart);
                let h = path_half_vectors(&geometry, job.eta)?;
                (geometry, h)
            }
        };
        let error = max_error(&h, target);
        let tolerance =
            settings.tolerance.min(settings.relative_tolerance * error).max(settings.precision_floor);
        Ok(WalkState {
            current: path.to_vec(),
            h,
            error,
            tolerance,
            errors: vec![error],
            step: 1.0,
            iteration: 0,
            candidate: 0,
            dx: Vec::new(),
            dx_current: false,
            geometry,
            pass: CorrectorPass::idle(),
            candidate_geometry: Vec::with_capacity(path.len()),
            candidate_h: Vec::with_capacity(target.len()),
        })
    }

    /// Runs the walk's arithmetic up to its next corrector row: `None` when that row's rays are needed,
    /// else the walk's outcome.
    fn advance(&mut self, job: &WalkJob, settings: &WalkSettings) -> Option<Result<WalkResult, WalkError>> {
        if self.pass.is_running() {
            return None;
        }
        if self.pass.is_finished() {
            let per_pass = if settings.candidates_at_once { CANDIDATES } else { 1 };
            if !self.take_best_candidate(job) {
                let next = self.candidate + per_pass;
                if next < CANDIDATES && self.fraction(next) >= settings.min_step {
                    // The same iteration, the next smaller candidates.
                    self.candidate = next;
                    self.restart_pass(per_pass, settings);
                    return None;
                }
                self.step *= 0.125;
            }
            if self.step < settings.min_step {
                return Some(Err(WalkError::DidNotConverge));
            }
            self.candidate = 0;
            self.iteration += 1;
        }
        if self.error <= self.tolerance {
            return Some(Ok(self.result()));
        }
        if self.iteration >= settings.max_iterations {
            return Some(Err(WalkError::DidNotConverge));
        }
        if !self.dx_current {
            let evaluated;
            let lu = match job.start {
                // No step taken yet: the iterate is the start path the caller factorised.
                Some(start) if self.errors.len() == 1 => start.lu,
                _ => {
                    let jacobian = match path_constraints(&self.geometry, job.eta) {
                        Ok(constraints) => constraints.jacobian,
                        Err(e) => return Some(Err(e.into())),
                    };
                    evaluated = match jacobian.into_factor() {
                        Ok(lu) => lu,
                        Err(s) => return Some(Err(WalkError::Singular { row: s.row })),
                    };
                    &evaluated
                }
            };
            let dh: Vec<DVec2> = job.target.iter().zip(&self.h).map(|(t, h)| *t - *h).collect();
            self.dx = lu.solve(&dh);
            self.dx_current = true;
        }
        self.restart_pass(if settings.candidates_at_once { CANDIDATES } else { 1 }, settings);
        None
    }

    /// Candidate `c`'s fraction of the Newton step in this iteration.
    fn fraction(&self, c: usize) -> f64 {
        self.step * 0.5f64.powi(c as i32)
    }

    /// Starts the corrector pass for up to `count` candidates from `self.candidate` on, those whose
    /// fraction is at least `settings.min_step`.
    fn restart_pass(&mut self, count: usize, settings: &WalkSettings) {
        let fractions: Vec<f64> = (self.candidate..self.candidate + count)
            .map(|c| self.fraction(c))
            .take_while(|&f| f >= settings.min_step)
            .collect();
        let (geometry, dx) = (&self.geometry, &self.dx);
        self.pass.restart(&self.current, &fractions, settings.visibility_every_pass, |i, fraction| {
            (geometry[i].p + geometry[i].displacement(dx[i - 1] * fraction)).as_vec3()
        });
    }

    /// Moves to the largest traced step whose candidate lowers the error (true), or leaves the iterate
    /// (false); leaves the pass idle.
    fn take_best_candidate(&mut self, job: &WalkJob) -> bool {
        self.pass.stop();
        let pass = &mut self.pass;
        for c in 0..pass.fractions.len() {
            if pass.status[c].is_err() {
                continue;
            }
            path_geometry_in_chart_into(&pass.built[c], job.chart, &mut self.candidate_geometry);
            if path_half_vectors_into(&self.candidate_geometry, job.eta, &mut self.candidate_h).is_err() {
                continue;
            }
            let new_error = max_error(&self.candidate_h, job.target);
            if new_error < self.error {
                let fraction = pass.fractions[c];
                // The old iterate's buffers become this candidate's for the next pass.
                std::mem::swap(&mut self.current, &mut pass.built[c]);
                std::mem::swap(&mut self.h, &mut self.candidate_h);
                std::mem::swap(&mut self.geometry, &mut self.candidate_geometry);
                self.error = new_error;
                self.errors.push(new_error);
                self.step = (fraction * 2.0).min(1.0);
                self.dx_current = false;
                return true;
            }
        }
        false
    }

    fn result(&mut self) -> WalkResult {
        WalkResult {
            path: std::mem::take(&mut self.current),
            h: std::mem::take(&mut self.h),
            errors: std::mem::take(&mut self.errors),
            iterations: self.iteration,
        }
    }
}
