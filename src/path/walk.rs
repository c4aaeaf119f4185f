//! Random walks that grow a sub-path from its endpoint (Veach 1997, §10.2): BSDF sampling at each
//! vertex, the area densities stored in both directions as the walk goes (the reverse one of a vertex is
//! known once its successor is sampled), Russian roulette on throughput·η² as in the path tracer. The
//! camera and light sub-paths of BDPT and the regenerated parts of MLT's bidirectional mutation all
//! grow here.

use super::{PathView, Vertex};
use crate::bsdf::{BsdfContext, BsdfLobe, TransportMode};
use crate::geometry::{Ray, Vec3};
use crate::render::SampleCounters;
use crate::sampling::{roulette, SampleSource};
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// How far a walk may go.
#[derive(Clone, Copy, Debug)]
pub struct WalkLimits {
    /// Most vertices the sub-path may hold, its endpoint included.
    pub max_vertices: usize,
    /// Russian roulette starts once the sub-path has this many segments (negative: never).
    pub rr_depth: i32,
}

/// Sets the density of a vertex as seen from the side the walk came from.
fn set_forward(v: &mut Vertex, mode: TransportMode, pdf: f32) {
    match mode {
        TransportMode::Radiance => v.pdf_from_camera = pdf,
        TransportMode::Importance => v.pdf_from_light = pdf,
    }
}

fn set_reverse(v: &mut Vertex, mode: TransportMode, pdf: f32) {
    set_forward(v, mode.flip(), pdf);
}

/// Once the last vertex of `path` is known, the vertex two before it gets its density as seen from
/// the other side (sampled from its successor, which was reached from the last vertex). Computed from
/// the vertex positions, exactly as `PathView::pdfs` recomputes it.
pub fn update_reverse_density(scene: &Scene, path: &mut [Vertex], mode: TransportMode) {
    let n = path.len();
    if n < 3 {
        return;
    }
    let pdf = PathView::density(scene, Some(&path[n - 1]), &path[n - 2], &path[n - 3], mode.flip());
    set_reverse(&mut path[n - 3], mode, pdf);
}

/// Extends `path` (holding at least its endpoint) along `ray`, which leaves the last vertex with
/// throughput `beta`. Returns the direction and throughput of the last ray if it escaped the scene,
/// so a camera walk can meet environment lights.
#[allow(clippy::too_many_arguments)] // the walk's whole state; a struct would only rename it
pub fn extend<S: SampleSource + ?Sized>(
    scene: &Scene,
    path: &mut Vec<Vertex>,
    mut ray: Ray,
    mut beta: Spectrum,
    mode: TransportMode,
    limits: WalkLimits,
    sampler: &mut S,
    counters: &mut SampleCounters,
) -> Option<(Vec3, Spectrum)> {
    // Relative IOR accumulated along the walk, so roulette judges radiance-like throughput.
    let mut eta_scale = 1.0f32;
    // Roulette judges the throughput relative to the walk's start: a light walk starts at Le·cos/pdf,
    // often far above 1, and judged absolutely it would only ever end by the survival cap, about 100
    // bounces on average at 0.99, however much its surfaces absorb (Mitsuba 0.5's walks start at 1).
    let start_scale = beta.max_element();
    let start_scale = if start_scale > 0.0 && start_scale.is_finite() { start_scale } else { 1.0 };
    while path.len() < limits.max_vertices {
        counters.rays += 1;
        let Some(si) = scene.intersect(&ray) else {
            return Some((ray.dir, beta));
        };
        let prev_index = path.len() - 1;
        let mut v = Vertex::surface(scene, &si, beta);
        let before = (prev_index >= 1).then(|| path[prev_index - 1]);
        let pdf_fwd = PathView::density(scene, before.as_ref(), &path[prev_index], &v, mode);
        set_forward(&mut v, mode, pdf_fwd);
        path.push(v);
        update_reverse_density(scene, path, mode);
        if path.len() >= limits.max_vertices {
            break;
        }

        let bsdf = scene.shapes[si.shape].bsdf.as_ref();
        let ctx = BsdfContext { mode, uv: si.uv };
        let wi_local = si.frame.to_local(si.wi);
        let u_lobe = sampler.next_1d();
        let u = sampler.next_2d();
        let Some(bs) = bsdf.sample(&ctx, wi_local, u_lobe, u) else { break };
        let wo = si.frame.to_world(bs.wo);
        let correction = crate::bsdf::shading_normal_correction(mode, si.wi, wo, si.ng, si.frame.n);
        let weight = bs.weight * correction;
        if !(bs.pdf > 0.0) || !weight.is_finite() || weight == Spectrum::ZERO {
            break;
        }
        if bs.lobe.is_delta() {
            // Dirac lobes have no density to store; MIS treats both as cancelling (see `mis_weight`).
            let cur = path.len() - 1;
            path[cur].delta = true;
        }
        beta *= weight;
        if bs.lobe.contains(BsdfLobe::TRANSMISSION) {
            eta_scale *= bs.eta;
        }
        let segments = (path.len() - 1) as i32;
        if limits.rr_depth >= 0 && segments >= limits.rr_depth {
            let q = roulette::survival_probability(beta.max_element() / start_scale * eta_scale * eta_scale);
            if !(sampler.next_1d() < q) {
                break;
            }
            beta /= q;
        }
        ray = si.spawn_ray(wo);
    }
    None
}
