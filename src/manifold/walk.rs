//! The Newton predictor–corrector walk on the constraint manifold (HSLT, Kaplanyan et al. 2014, Sec. 5.1;
//! Jakob and Marschner 2012 for the specular case): move the inner vertices of a path with fixed ends
//! until their half vectors reach given targets (zero at specular vertices for MEMLT, any for HSLT).

use glam::{DVec2, Vec3};

use super::constraint::{path_constraints, path_geometry, ConstraintError};
use crate::accel::Hit;
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
    /// Cast each corrector pass's rays (one per candidate step size) as one batched query; false casts
    /// them one at a time (`hslt bench hslt` measures both).
    pub batch_rays: bool,
}

impl Default for WalkSettings {
    fn default() -> Self {
        WalkSettings {
            max_iterations: 20,
            tolerance: 1e-5,
            relative_tolerance: 1e-3,
            precision_floor: 2e-6,
            min_step: 1e-5,
            batch_rays: true,
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
    assert!(path.len() >= 3 && target.len() == path.len() - 2, "one target per inner vertex");
    let mut current = path.to_vec();
    let mut constraints = path_constraints(&path_geometry(&current), eta)?;
    let mut error = max_error(&constraints.h, target);
    let tolerance = settings.tolerance.min(settings.relative_tolerance * error).max(settings.precision_floor);
    let mut errors = vec![error];
    let mut step: f64 = 1.0;
    for iteration in 0..settings.max_iterations {
        if error <= tolerance {
            return Ok(WalkResult { path: current, h: constraints.h, errors, iterations: iteration });
        }
        let lu = constraints.jacobian.factor().map_err(|s| WalkError::Singular { row: s.row })?;
        let dh: Vec<DVec2> = target.iter().zip(&constraints.h).map(|(t, h)| *t - *h).collect();
        let dx = lu.solve(&dh);
        let geometry = path_geometry(&current);
        // Three step sizes at once, so each corrector ray cast is a batch (digest 2.5's halving,
        // three halvings per pass).
        let fractions = [step, step * 0.5, step * 0.25];
        let candidates = corrector_pass_counting_rays(
            scene,
            &current,
            &fractions,
            |i, fraction| (geometry[i].p + geometry[i].displacement(dx[i - 1] * fraction)).as_vec3(),
            settings.batch_rays,
            rays,
        );
        let mut accepted = false;
        for (fraction, candidate) in fractions.into_iter().zip(candidates) {
            let Ok(moved) = candidate else { continue };
            let Ok(new_constraints) = path_constraints(&path_geometry(&moved), eta) else { continue };
            let new_error = max_error(&new_constraints.h, target);
            if new_error < error {
                current = moved;
                constraints = new_constraints;
                error = new_error;
                errors.push(error);
                step = (fraction * 2.0).min(1.0);
                accepted = true;
                break;
            }
        }
        if !accepted {
            step *= 0.125;
            if step < settings.min_step {
                return Err(WalkError::DidNotConverge);
            }
        }
    }
    if error <= tolerance {
        return Ok(WalkResult {
            path: current,
            h: constraints.h,
            errors,
            iterations: settings.max_iterations,
        });
    }
    Err(WalkError::DidNotConverge)
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
    let k = current.len() - 1;
    let mut out: Vec<Result<Vec<Vertex>, CorrectorFailure>> =
        fractions.iter().map(|_| Ok(vec![current[0]])).collect();
    let mut rays = Vec::with_capacity(fractions.len());
    let mut owners = Vec::with_capacity(fractions.len());
    let mut hits: Vec<Option<Hit>> = Vec::new();
    for i in 1..k {
        rays.clear();
        owners.clear();
        for (c, candidate) in out.iter().enumerate() {
            let Ok(built) = candidate else { continue };
            let from = built[i - 1];
            let target = predicted(i, fractions[c]);
            let Some(dir) = (target - from.p).try_normalize() else { continue };
            let origin = if from.is_surface() { offset_origin(from.p, from.ng, dir) } else { from.p };
            // Aim from the offset origin: a ray parallel to from→target but displaced by the origin
            // offset (1e-4 relative) lands that far from the prediction, a noise floor the walk then
            // cannot converge below.
            let Some(dir) = (target - origin).try_normalize() else { continue };
            rays.push(Ray::new(origin, dir));
            owners.push(c);
        }
        hits.clear();
        hits.resize(rays.len(), None);
        if batched {
            scene.accel().intersect_batch(&rays, &mut hits);
        } else {
            for (ray, hit) in rays.iter().zip(hits.iter_mut()) {
                *hit = scene.accel().intersect(ray);
            }
        }
        *rays_cast += rays.len() as u64;
        for ((ray, hit), &c) in rays.iter().zip(&hits).zip(&owners) {
            let result = match hit.as_ref().and_then(|h| SurfaceInteraction::from_hit(scene, ray, h)) {
                None => Err(CorrectorFailure::Missed { vertex: i }),
                Some(si) if si.shape != current[i].shape => Err(CorrectorFailure::OtherShape { vertex: i }),
                Some(si) => Ok(Vertex::surface(scene, &si, current[i].beta)),
            };
            match result {
                Ok(v) => {
                    if let Ok(built) = &mut out[c] {
                        built.push(v);
                    }
                }
                Err(e) => out[c] = Err(e),
            }
        }
        // Candidates whose ray was never cast (degenerate aim) fail here.
        for candidate in out.iter_mut() {
            if matches!(candidate, Ok(built) if built.len() != i + 1) {
                *candidate = Err(CorrectorFailure::Missed { vertex: i });
            }
        }
    }
    for candidate in out.iter_mut() {
        let Ok(built) = candidate else { continue };
        built.push(current[k]);
        let end = current[k];
        let near = built[k - 1];
        let end_normal = if end.is_surface() { end.ng } else { Vec3::ZERO };
        *rays_cast += 1;
        if scene.occluded_between(near.p, near.ng, end.p, end_normal) {
            *candidate = Err(CorrectorFailure::Occluded);
            continue;
        }
        if let Some(i) = (1..k).find(|&i| same_side_sign(built, i) != same_side_sign(current, i)) {
            *candidate = Err(CorrectorFailure::ChangedSide { vertex: i });
        }
    }
    out
}
