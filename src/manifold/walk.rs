//! The Newton predictor–corrector walk on the constraint manifold (HSLT, Kaplanyan et al. 2014, Sec. 5.1;
//! Jakob and Marschner 2012 for the specular case): move the inner vertices of a path with fixed ends
//! until their half vectors reach given targets (zero at specular vertices for MEMLT, any for HSLT).
//! Walks are resumable states advanced one corrector row at a time, so `walk_many` can put the rays of
//! many walks in flight into one batched query (issue #7); `walk` is `walk_many` with one job.

use glam::{DVec2, DVec3, Vec3};

use super::constraint::{
    path_constraints, path_geometry_in_chart, ConstraintError, LocalGeometry, PathConstraints,
};
use crate::accel::{Hit, RayQuery};
use crate::geometry::{offset_origin, Ray};
use crate::path::Vertex;
use crate::scene::{Scene, SurfaceInteraction};

/// Constants of the walk (digest 2.5 lists what open implementations use).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkSettings {
    pub max_iterations: usize,
    /// Converged when every |h_i − target_i| is below `min(tolerance, relative_tolerance · initial
    /// error)`, but never asked below `precision_floor` (vertices are stored in f32).
    pub tolerance: f64,
    pub relative_tolerance: f64,
    pub precision_floor: f64,
    /// Give up once the step fraction falls below this.
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
}

impl WalkError {
    /// The short name mutations count this failure under in their statistics.
    pub fn reason(self) -> &'static str {
        match self {
            WalkError::Singular { .. } => "singular",
            WalkError::Constraint(_) => "degenerate",
            WalkError::DidNotConverge => "did_not_converge",
        }
    }
}

/// Why one corrector pass at one step size was refused (the walk then halves the step).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CorrectorFailure {
    /// The ray towards vertex `vertex` hit nothing.
    Missed {
        vertex: usize,
    },
    /// It hit another shape than the one the vertex lies on.
    OtherShape {
        vertex: usize,
    },
    /// Reflection turned into transmission or back at `vertex`.
    ChangedSide {
        vertex: usize,
    },
    /// The last segment to the fixed end is blocked.
    Occluded,
    Constraint(ConstraintError),
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

fn same_side_sign(path: &[Vertex], i: usize) -> bool {
    let ng = path[i].ng;
    (ng.dot(path[i - 1].p - path[i].p) * ng.dot(path[i + 1].p - path[i].p)) > 0.0
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
    let job = WalkJob { path, eta, target, chart };
    let mut results = walk_many(scene, &[job], settings, std::slice::from_mut(rays));
    results.pop().expect("one result per job")
}

/// Runs all `jobs` together: each round, every unfinished walk contributes the rays of its current
/// corrector row, and they are cast as one batch (Embree packets), so walks in flight share packets.
/// Each walk runs the same steps as alone, so its result is `walk`'s bit for bit unless one of its rays
/// hits two triangles at the same distance, a tie Embree breaks by traversal order, which depends on
/// the packet's other rays (about 1 walk in 5000 at 64 in flight on jewelry; docs/benchmarks.md).
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
    let mut batch = RayBatch::default();
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
    results.into_iter().map(|r| r.expect("every job finishes")).collect()
}

/// A walk between two ray queries: the Newton iterate, its constraints and the corrector pass in flight.
struct WalkState {
    current: Vec<Vertex>,
    constraints: PathConstraints,
    error: f64,
    tolerance: f64,
    errors: Vec<f64>,
    step: f64,
    iteration: usize,
    /// The first candidate (0 = the full step) the pass in flight traces.
    candidate: usize,
    /// This iteration's Newton direction and the geometry it was computed at.
    dx: Vec<DVec2>,
    geometry: Vec<LocalGeometry>,
    /// The pass of iteration `iteration`, or an empty one before the first.
    pass: CorrectorPass,
}

impl WalkState {
    fn start(job: &WalkJob, settings: &WalkSettings) -> Result<WalkState, WalkError> {
        let (path, target) = (job.path, job.target);
        assert!(path.len() >= 3 && target.len() == path.len() - 2, "one target per inner vertex");
        let constraints = path_constraints(&path_geometry_in_chart(path, job.chart), job.eta)?;
        let error = max_error(&constraints.h, target);
        let tolerance =
            settings.tolerance.min(settings.relative_tolerance * error).max(settings.precision_floor);
        Ok(WalkState {
            current: path.to_vec(),
            constraints,
            error,
            tolerance,
            errors: vec![error],
            step: 1.0,
            iteration: 0,
            candidate: 0,
            dx: Vec::new(),
            geometry: Vec::new(),
            pass: CorrectorPass::idle(),
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
                if self.candidate + per_pass < CANDIDATES {
                    // The same iteration, the next smaller candidates.
                    self.candidate += per_pass;
                    self.restart_pass(per_pass);
                    return None;
                }
                self.step *= 0.125;
                if self.step < settings.min_step {
                    return Some(Err(WalkError::DidNotConverge));
                }
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
        let lu = match self.constraints.jacobian.factor() {
            Ok(lu) => lu,
            Err(s) => return Some(Err(WalkError::Singular { row: s.row })),
        };
        let dh: Vec<DVec2> = job.target.iter().zip(&self.constraints.h).map(|(t, h)| *t - *h).collect();
        self.dx = lu.solve(&dh);
        self.geometry = path_geometry_in_chart(&self.current, job.chart);
        self.restart_pass(if settings.candidates_at_once { CANDIDATES } else { 1 });
        None
    }

    /// Starts the corrector pass for `count` candidates from `self.candidate` on.
    fn restart_pass(&mut self, count: usize) {
        let fractions: Vec<f64> =
            (self.candidate..self.candidate + count).map(|c| self.step * 0.5f64.powi(c as i32)).collect();
        let (geometry, dx) = (&self.geometry, &self.dx);
        self.pass.restart(&self.current, &fractions, |i, fraction| {
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
            let Ok(new_constraints) =
                path_constraints(&path_geometry_in_chart(&pass.built[c], job.chart), job.eta)
            else {
                continue;
            };
            let new_error = max_error(&new_constraints.h, job.target);
            if new_error < self.error {
                let fraction = pass.fractions[c];
                // The old iterate's buffer becomes this candidate's for the next pass.
                std::mem::swap(&mut self.current, &mut pass.built[c]);
                self.constraints = new_constraints;
                self.error = new_error;
                self.errors.push(new_error);
                self.step = (fraction * 2.0).min(1.0);
                return true;
            }
        }
        false
    }

    fn result(&mut self) -> WalkResult {
        WalkResult {
            path: std::mem::take(&mut self.current),
            h: std::mem::take(&mut self.constraints.h),
            errors: std::mem::take(&mut self.errors),
            iterations: self.iteration,
        }
    }
}

/// Projects predicted positions back onto the scene for several step fractions at once: for each inner
/// vertex in turn, one batch of rays (one per live candidate) from the candidate's new previous vertex
/// through its predicted position, then one batch of visibility rays to the fixed end.
pub fn corrector_pass(
    scene: &Scene,
    current: &[Vertex],
    fractions: &[f64],
    predicted: impl Fn(usize, f64) -> Vec3,
) -> Vec<Result<Vec<Vertex>, CorrectorFailure>> {
    corrector_pass_counting_rays(scene, current, fractions, predicted, true, &mut 0)
}

/// `corrector_pass`, adding the rays it casts to `rays`; `batched` = false casts them one by one.
pub fn corrector_pass_counting_rays(
    scene: &Scene,
    current: &[Vertex],
    fractions: &[f64],
    predicted: impl Fn(usize, f64) -> Vec3,
    batched: bool,
    rays_cast: &mut u64,
) -> Vec<Result<Vec<Vertex>, CorrectorFailure>> {
    let mut pass = CorrectorPass::idle();
    pass.restart(current, fractions, predicted);
    let mut batch = RayBatch::default();
    while pass.is_running() {
        batch.clear();
        let slot = pass.emit(current, &mut batch);
        *rays_cast += slot.len as u64;
        batch.cast(scene.accel(), batched);
        pass.absorb(scene, current, &batch, &slot);
    }
    pass.built.into_iter().zip(pass.status).map(|(built, status)| status.map(|()| built)).collect()
}

/// One corrector pass in flight: one candidate path per step fraction, built vertex by vertex. Row i
/// (1 ≤ i < k) casts the rays that place vertex i, row k the visibility rays to the fixed end x_k.
struct CorrectorPass {
    fractions: Vec<f64>,
    /// `predicted[c * (k - 1) + i - 1]`: where candidate c's inner vertex i should land.
    predicted: Vec<Vec3>,
    /// Candidate c's vertices so far; only meaningful while `status[c]` is Ok. The buffers are reused
    /// from pass to pass, so a walk allocates them once.
    built: Vec<Vec<Vertex>>,
    status: Vec<Result<(), CorrectorFailure>>,
    /// The row whose rays are next; 0 for the idle pass before a walk's first iteration.
    row: usize,
    /// The path length k + 1, or 0 when idle.
    len: usize,
    /// The candidates whose rays are in flight, in the order they were emitted.
    owners: Vec<usize>,
}

/// Where one corrector row's rays went in a `RayBatch`.
#[derive(Clone, Copy, Debug)]
struct Slot {
    bucket: Bucket,
    start: usize,
    len: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bucket {
    /// Rays leaving x_0: every walk of one camera shares that origin, so packets of these rays get
    /// Embree's coherent traversal (see `intersect_batch`).
    FromStart,
    Inner,
    Visibility,
}

/// The rays of one round of corrector rows, across walks, and their answers.
#[derive(Default)]
struct RayBatch {
    from_start: Vec<Ray>,
    inner: Vec<Ray>,
    visibility: Vec<Ray>,
    from_start_hits: Vec<Option<Hit>>,
    inner_hits: Vec<Option<Hit>>,
    occluded: Vec<bool>,
}

impl RayBatch {
    fn clear(&mut self) {
        self.from_start.clear();
        self.inner.clear();
        self.visibility.clear();
    }

    fn rays_mut(&mut self, bucket: Bucket) -> &mut Vec<Ray> {
        match bucket {
            Bucket::FromStart => &mut self.from_start,
            Bucket::Inner => &mut self.inner,
            Bucket::Visibility => &mut self.visibility,
        }
    }

    fn rays(&self, slot: &Slot) -> &[Ray] {
        let rays = match slot.bucket {
            Bucket::FromStart => &self.from_start,
            Bucket::Inner => &self.inner,
            Bucket::Visibility => &self.visibility,
        };
        &rays[slot.start..slot.start + slot.len]
    }

    fn hits(&self, slot: &Slot) -> &[Option<Hit>] {
        let hits = match slot.bucket {
            Bucket::FromStart => &self.from_start_hits,
            Bucket::Inner => &self.inner_hits,
            Bucket::Visibility => unreachable!("visibility rows have no hits"),
        };
        &hits[slot.start..slot.start + slot.len]
    }

    /// One query per bucket (`batched`), or every ray on its own.
    fn cast(&mut self, accel: &dyn RayQuery, batched: bool) {
        for (rays, hits) in
            [(&self.from_start, &mut self.from_start_hits), (&self.inner, &mut self.inner_hits)]
        {
            hits.clear();
            hits.resize(rays.len(), None);
            if batched {
                accel.intersect_batch(rays, hits);
            } else {
                for (ray, hit) in rays.iter().zip(hits.iter_mut()) {
                    *hit = accel.intersect(ray);
                }
            }
        }
        self.occluded.clear();
        self.occluded.resize(self.visibility.len(), false);
        if batched {
            accel.occluded_batch(&self.visibility, &mut self.occluded);
        } else {
            for (ray, blocked) in self.visibility.iter().zip(self.occluded.iter_mut()) {
                *blocked = accel.occluded(ray);
            }
        }
    }
}

impl CorrectorPass {
    fn idle() -> CorrectorPass {
        CorrectorPass {
            fractions: Vec::new(),
            predicted: Vec::new(),
            built: Vec::new(),
            status: Vec::new(),
            row: 0,
            len: 0,
            owners: Vec::new(),
        }
    }

    /// Starts a pass from `current` with one candidate per step fraction.
    fn restart(&mut self, current: &[Vertex], fractions: &[f64], predicted: impl Fn(usize, f64) -> Vec3) {
        let k = current.len() - 1;
        self.fractions.clear();
        self.fractions.extend_from_slice(fractions);
        self.predicted.clear();
        self.predicted.extend(
            fractions.iter().flat_map(|&f| (1..k).map(move |i| (i, f))).map(|(i, f)| predicted(i, f)),
        );
        self.built.resize_with(fractions.len(), Vec::new);
        for built in &mut self.built {
            built.clear();
            built.reserve(current.len());
            built.push(current[0]);
        }
        self.status.clear();
        self.status.resize(fractions.len(), Ok(()));
        self.row = 1;
        self.len = current.len();
    }

    /// Makes the pass idle (neither running nor finished), keeping its buffers.
    fn stop(&mut self) {
        self.row = 0;
        self.len = 0;
    }

    fn is_running(&self) -> bool {
        self.row >= 1 && self.row < self.len
    }

    fn is_finished(&self) -> bool {
        self.len > 0 && self.row >= self.len
    }

    /// Appends the current row's rays to `batch`.
    fn emit(&mut self, current: &[Vertex], batch: &mut RayBatch) -> Slot {
        let k = current.len() - 1;
        let i = self.row;
        self.owners.clear();
        let bucket = match i {
            1 => Bucket::FromStart,
            _ if i < k => Bucket::Inner,
            _ => Bucket::Visibility,
        };
        let rays = batch.rays_mut(bucket);
        let start = rays.len();
        for (c, (built, status)) in self.built.iter().zip(self.status.iter_mut()).enumerate() {
            if status.is_err() {
                continue;
            }
            if i == k {
                let (near, end) = (built[k - 1], current[k]);
                match Scene::shadow_segment(near.p, near.offset(), end.p, end.offset()) {
                    Some(ray) => {
                        rays.push(ray);
                        self.owners.push(c);
                    }
                    None => *status = Err(CorrectorFailure::Occluded),
                }
                continue;
            }
            let from = built[i - 1];
            let target = self.predicted[c * (k - 1) + i - 1];
            let Some(dir) = (target - from.p).try_normalize() else {
                *status = Err(CorrectorFailure::Missed { vertex: i });
                continue;
            };
            let origin = offset_origin(from.p, from.offset(), dir);
            // Aim from the offset origin: a ray parallel to from→target but displaced by the origin
            // offset (1e-4 relative) lands that far from the prediction, a noise floor the walk then
            // cannot converge below.
            let Some(dir) = (target - origin).try_normalize() else {
                *status = Err(CorrectorFailure::Missed { vertex: i });
                continue;
            };
            rays.push(Ray::new(origin, dir));
            self.owners.push(c);
        }
        Slot { bucket, start, len: rays.len() - start }
    }

    /// Takes the answers to the rays `emit` put in `slot` and moves to the next row.
    fn absorb(&mut self, scene: &Scene, current: &[Vertex], batch: &RayBatch, slot: &Slot) {
        let k = current.len() - 1;
        let i = self.row;
        self.row += 1;
        if slot.bucket == Bucket::Visibility {
            let blocked = &batch.occluded[slot.start..slot.start + slot.len];
            for (&c, &blocked) in self.owners.iter().zip(blocked) {
                let built = &mut self.built[c];
                built.push(current[k]);
                let failure = if blocked {
                    Some(CorrectorFailure::Occluded)
                } else {
                    (1..k)
                        .find(|&v| same_side_sign(built, v) != same_side_sign(current, v))
                        .map(|vertex| CorrectorFailure::ChangedSide { vertex })
                };
                if let Some(failure) = failure {
                    self.status[c] = Err(failure);
                }
            }
            return;
        }
        for ((ray, hit), &c) in batch.rays(slot).iter().zip(batch.hits(slot)).zip(&self.owners) {
            let result = match hit.as_ref().and_then(|h| SurfaceInteraction::from_hit(scene, ray, h)) {
                None => Err(CorrectorFailure::Missed { vertex: i }),
                Some(si) if si.shape != current[i].shape => Err(CorrectorFailure::OtherShape { vertex: i }),
                Some(si) => Ok(Vertex::surface(scene, &si, current[i].beta)),
            };
            match result {
                Ok(v) => self.built[c].push(v),
                Err(e) => self.status[c] = Err(e),
            }
        }
    }
}
