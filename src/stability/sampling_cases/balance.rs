//! Case 12: detailed balance of the HSLT mutation on the smallest scene where f_H is known: a glossy
//! plane, a point light and a pinhole (digest §5.12). The chain's stationary histogram of h_1 must be
//! ∫_bin f_H dh (evaluated on a fine grid of the plane, where f_H dh = f_A dA), and for random pairs
//! f(X)T(X→Y)a(X→Y) = f(Y)T(Y→X)a(Y→X) with |det J| from finite differences of our own h(x).

use glam::{DVec2, DVec3};

use super::{bdpt_for, f1_moments, glossy_plane_xml, mean_se, seeding, target};
use crate::geometry::Ray;
use crate::integrators::Bdpt;
use crate::manifold::{path_constraints, path_etas, path_geometry, LocalGeometry};
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{
    Chain, Mutation, MutationStats, PathContext, PathState, TargetFunction, WeightedMutation,
};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

const PLANE_HALF_SIZE: f64 = 1.5;
const BINS: usize = 6;

pub fn run(effort: Effort) -> CaseReport {
    let scene = from_xml("balance-plane", &glossy_plane_xml(0.3, PLANE_HALF_SIZE, 32, 24));
    let bdpt = bdpt_for(&scene);
    let mut report = CaseReport::new();
    stationary_histogram(&scene, &bdpt, effort, &mut report);
    pairwise_identity(&scene, &bdpt, effort, &mut report);
    report
}

fn half_vector_of(scene: &Scene, path: &[Vertex]) -> Option<(DVec2, f64)> {
    let c = path_constraints(&path_geometry(path), &path_etas(scene, path)).ok()?;
    let ln_det = c.jacobian.factor().ok()?.log_det().ln_abs;
    Some((c.h[0], ln_det))
}

/// The h_1 bins: a BINS² grid over the box of half vectors that carry light.
struct Bins {
    lo: DVec2,
    size: DVec2,
}

impl Bins {
    fn index(&self, h: DVec2) -> Option<usize> {
        let c = (h - self.lo) / self.size;
        (c.x >= 0.0 && c.y >= 0.0 && c.x < BINS as f64 && c.y < BINS as f64)
            .then(|| c.y as usize * BINS + c.x as usize)
    }
}

/// Mass per h_1 bin of the target f_H (and, for the power check, of f_A taken as a density in h,
/// which is what a ratio without |det J| would make stationary), by the midpoint rule on a grid of the
/// plane: every x_1 on it is a path camera → x_1 → light, and ∫_bin f_H dh = ∫_{h(x) ∈ bin} f_A dA.
fn expected_masses(scene: &Scene, x0: &Vertex, x2: &Vertex, grid: usize) -> (Bins, Vec<f64>, Vec<f64>) {
    let cell = 2.0 * PLANE_HALF_SIZE / grid as f64;
    let mut points = Vec::new();
    for iy in 0..grid {
        for ix in 0..grid {
            let q = DVec3::new(
                -PLANE_HALF_SIZE + (ix as f64 + 0.5) * cell,
                -PLANE_HALF_SIZE + (iy as f64 + 0.5) * cell,
                0.0,
            );
            let dir = (q - x0.p.as_dvec3()).normalize().as_vec3();
            let Some(si) = scene.intersect(&Ray::new(x0.p, dir)) else { continue };
            let path = vec![*x0, Vertex::surface(scene, &si, Spectrum::ONE), *x2];
            let Some(state) = PathState::new(scene, path) else { continue };
            let Some((h, ln_det)) = half_vector_of(scene, &state.vertices) else { continue };
            points.push((h, target(&state) * cell * cell, ln_det.exp()));
        }
    }
    let peak = points.iter().map(|p| p.1).fold(0.0, f64::max);
    let carrying = points.iter().filter(|p| p.1 > 1e-4 * peak);
    let (lo, hi) =
        carrying.fold((DVec2::splat(1.0), DVec2::splat(-1.0)), |(lo, hi), p| (lo.min(p.0), hi.max(p.0)));
    // A margin so half vectors at the edge of the box fall inside.
    let margin = (hi - lo) * 1e-3;
    let bins = Bins { lo: lo - margin, size: (hi - lo + 2.0 * margin) / BINS as f64 };
    let (mut f_h, mut f_a) = (vec![0.0; BINS * BINS], vec![0.0; BINS * BINS]);
    for (h, mass, det) in points {
        if let Some(b) = bins.index(h) {
            f_h[b] += mass;
            f_a[b] += mass * det;
        }
    }
    let normalise = |v: &mut Vec<f64>| {
        let total: f64 = v.iter().sum();
        v.iter_mut().for_each(|m| *m /= total);
    };
    normalise(&mut f_h);
    normalise(&mut f_a);
    (bins, f_h, f_a)
}

fn stationary_histogram(scene: &Scene, bdpt: &Bdpt, effort: Effort, report: &mut CaseReport) {
    let runs = 16;
    let (chains, steps) = (effort.scale(256, 1024), effort.scale(30, 60));
    let first = seeding(scene, bdpt, 500, 20_000);
    let mut rng = Sampler::new(500, 0, 0);
    let start = (0..100)
        .find_map(|_| first.draw(scene, bdpt, 500, rng.next_f64()))
        .expect("the plane reflects light");
    if start.vertices.len() != 3 {
        report.check(false, "the tiny scene's paths must be camera → plane → light");
        return;
    }
    let (x0, x2) = (start.vertices[0], start.vertices[2]);
    let (bins, f_h, f_a) = expected_masses(scene, &x0, &x2, effort.scale(300, 600));
    let mut per_run: Vec<Vec<f64>> = Vec::new();
    let mut stats = MutationStats::default();
    let mut outside = 0u64;
    for run in 0..runs {
        let seed = 600 + run as u64;
        // Each run seeds afresh: the starts are resampled from a finite seeding pass, and only
        // independent passes make the spread between runs an honest error of the histogram.
        let seeds = seeding(scene, bdpt, seed, 20_000);
        let mut rng = Sampler::new(seed, 1, 0);
        let mut counts = vec![0.0; BINS * BINS];
        let mut recorded = 0.0;
        for c in 0..chains {
            let Some(start) = (0..20).find_map(|_| seeds.draw(scene, bdpt, seed, rng.next_f64())) else {
                continue;
            };
            let mutation = Box::new(HalfVectorMutation::new(HalfVectorParams::default()));
            let mut chain = Chain::new(
                start,
                vec![WeightedMutation { mutation, weight: 1.0 }],
                TargetFunction::Luminance,
                Sampler::new(seed, c as u64, 2),
            );
            let mut ctx = PathContext::new(scene, bdpt);
            for _ in 0..steps {
                chain.step(&mut ctx, &mut |_: &PathState, _| {});
                let state = chain.current();
                match half_vector_of(scene, &state.vertices).and_then(|(h, _)| bins.index(h)) {
                    Some(b) => counts[b] += 1.0,
                    None => outside += 1,
                }
                recorded += 1.0;
            }
            stats.add(&chain.stats()[0]);
        }
        per_run.push(counts.iter().map(|c| c / recorded).collect());
    }
    // t² per bin of the run mean against the exact mass follows F(1, runs − 1); the mean over n
    // roughly independent bins has sd √(var/n), and the bound is five of them above the mean.
    let statistic = |expected: &[f64]| {
        let mut t2 = Vec::new();
        for (b, &e) in expected.iter().enumerate() {
            let col: Vec<f64> = per_run.iter().map(|r| r[b]).collect();
            let (m, se) = mean_se(&col);
            if e > 0.005 && se > 0.0 {
                t2.push(((m - e) / se).powi(2));
            }
        }
        (t2.iter().sum::<f64>() / t2.len().max(1) as f64, t2.len())
    };
    let (t2_fh, n_bins) = statistic(&f_h);
    let (t2_fa, _) = statistic(&f_a);
    let (mean, var) = f1_moments((runs - 1) as f64);
    let bound = mean + 5.0 * (var / n_bins.max(1) as f64).sqrt();
    let applicable = stats.proposed - stats.not_applicable;
    report.measure(format!(
        "h_1 histogram ({runs} runs × {chains} chains × {steps} steps, {n_bins} bins with > 0.5% of f_H): mean t² \
         against f_H {t2_fh:.2} (bound {bound:.2}), against f_A-in-h (no |det J|) {t2_fa:.1}; acceptance {:.3}, \
         {outside} states outside the bins",
        stats.accepted as f64 / applicable.max(1) as f64
    ));
    report.check(n_bins >= 10, format!("only {n_bins} populated bins: the histogram checks little"));
    report.check(stats.accepted * 10 > applicable, "the chains hardly move: the histogram is the seeds'");
    report.check(
        t2_fh < bound,
        format!("stationary h_1 differs from f_H: mean t² {t2_fh:.2} (bound {bound:.2})"),
    );
    // Power: the same statistic must tell f_H from the density a ratio without |det J| targets.
    report.check(t2_fa > bound, format!("the histogram cannot tell f_H from f_A in h ({t2_fa:.2})"));
}

/// h⊥ at x_1 = `p` between fixed x_0 and x_2, written out afresh (not the manifold code): the
/// normalised H = wi + wo in the vertex's (s, t) frame. The plane is flat, so the frame is constant.
fn own_half_vector(x0: DVec3, p: DVec3, x2: DVec3, frame: (DVec3, DVec3, DVec3)) -> DVec2 {
    let (s, t, n) = frame;
    let h = ((x0 - p).normalize() + (x2 - p).normalize()).normalize();
    let h = if h.dot(n) < 0.0 { -h } else { h };
    DVec2::new(h.dot(s), h.dot(t))
}

/// ln |det ∂h/∂x_1| by central differences along the vertex's orthonormal tangents.
fn own_ln_det(path: &[Vertex]) -> (DVec2, f64) {
    let g = LocalGeometry::from_vertex(&path[1]);
    let (s, t) = g.shading_frame().expect("the plane has a frame");
    let frame = (s, t, g.n);
    let (x0, x2) = (path[0].p.as_dvec3(), path[2].p.as_dvec3());
    // 1e-5 of an O(1) scene: truncation ~1e-10 and rounding ~1e-11 relative, far below the 1e-6
    // tolerance below and far above f64 noise.
    let step = 1e-5;
    let col = |d: DVec3| {
        (own_half_vector(x0, g.p + d * step, x2, frame) - own_half_vector(x0, g.p - d * step, x2, frame))
            / (2.0 * step)
    };
    let (cu, cv) = (col(g.tu), col(g.tv));
    (own_half_vector(x0, g.p, x2, frame), (cu.x * cv.y - cu.y * cv.x).abs().ln())
}

fn pairwise_identity(scene: &Scene, bdpt: &Bdpt, effort: Effort, report: &mut CaseReport) {
    let draws = effort.scale(3000, 30_000);
    let seeds = seeding(scene, bdpt, 700, 20_000);
    let mut mutation = HalfVectorMutation::new(HalfVectorParams::default());
    let mut ctx = PathContext::new(scene, bdpt);
    let mut rng = Sampler::new(700, 3, 0);
    let mut stats = MutationStats::default();
    let (mut pairs, mut worst, mut det_shift) = (0usize, 0.0f64, Vec::new());
    for _ in 0..draws {
        let Some(x) = seeds.draw(scene, bdpt, 700, rng.next_f64()) else { continue };
        let Ok(p) = mutation.propose(&x, &mut ctx, &mut rng, &mut stats) else { continue };
        let y = &p.state;
        if !(p.t_ratio > 0.0) {
            continue;
        }
        let (Ok(prep_x), Ok(prep_y)) =
            (mutation.prepare(scene, &x.vertices, x.film), mutation.prepare(scene, &y.vertices, y.film))
        else {
            continue;
        };
        let ((hx, ln_det_x), (hy, ln_det_y)) = (own_ln_det(&x.vertices), own_ln_det(&y.vertices));
        let (Some(ln_q_xy), Some(ln_q_yx)) = (prep_x.log_density(&[hy]), prep_y.log_density(&[hx])) else {
            continue;
        };
        // T in area measure: the kernel's density in h times |∂h/∂x_1| at the proposed end.
        let ln_t_xy = ln_q_xy + ln_det_y;
        let ln_t_yx = ln_q_yx + ln_det_x;
        let r = target(y) * p.t_ratio / target(&x);
        let (a_xy, a_yx) = (r.min(1.0), (1.0 / r).min(1.0));
        let lhs = target(&x).ln() + ln_t_xy + a_xy.ln();
        let rhs = target(y).ln() + ln_t_yx + a_yx.ln();
        worst = worst.max((lhs - rhs).abs());
        det_shift.push((ln_det_x - ln_det_y).abs());
        pairs += 1;
    }
    det_shift.sort_by(f64::total_cmp);
    let median_shift = det_shift.get(det_shift.len() / 2).copied().unwrap_or(0.0);
    report.measure(format!(
        "pairwise identity on {pairs} accepted-able pairs: max |ln f(X)T(X→Y)a(X→Y) − ln f(Y)T(Y→X)a(Y→X)| \
         {worst:.1e} (|det J| by finite differences; leaving it out would shift it by a median {median_shift:.1e})"
    ));
    report.check(pairs > draws / 4, format!("only {pairs} of {draws} proposals gave a pair"));
    // Both sides use independent determinants (analytic in the ratio, finite differences here) whose
    // relative disagreement is ~1e-8; 1e-6 allows for that and nothing more.
    report.check(worst < 1e-6, format!("detailed balance broken by {worst:.2e} in ln"));
    report.check(median_shift > 1e-4, "the pairs barely change |det J|: the identity checks little");
}
