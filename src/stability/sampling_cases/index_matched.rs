//! Case 10: index-matched ("null") interfaces (digest §5.10 and 2.1): a smooth dielectric sheet with
//! int_ior = ext_ior above a glossy plane. Its constraint must take the unnormalised form with the
//! solution H~ = 0, enter f_H with the factor 1 (the product-of-Jacobians identity of digest 2.4 with
//! |dω⊥_o/dh| = |n_g·ω_o|/|n·ω_o|), let the Newton walk converge through it, and take no step share:
//! HSLT holds it at h = 0 as a Dirac vertex; HSLT and MEMLT keep detailed balance through it.

use glam::DVec2;

use super::{bdpt_for, failures, mean_se, seeding, target};
use crate::integrators::Bdpt;
use crate::manifold::{
    direction_per_half_vector, half_vector_constraint, path_constraints, path_etas, path_geometry, walk,
    WalkSettings,
};
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{Failure, ManifoldPerturbation, Mutation, MutationStats, PathContext, PathState};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

const SCENE: &str = r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="3" /></integrator>
  <sensor type="perspective">
    <float name="fov" value="45" />
    <transform name="to_world"><lookat origin="0, -4, 3" target="0, 0, 0" up="0, 0, 1" /></transform>
    <film type="hdrfilm"><integer name="width" value="32" /><integer name="height" value="24" /></film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="10" /><rotate x="1" angle="8" /><translate z="1.2" /></transform>
    <bsdf type="dielectric"><float name="int_ior" value="1.0" /><float name="ext_ior" value="1.0" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="10" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="0.2" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="0.2" y="1.0" z="0.8" /><rgb name="intensity" value="10, 10, 10" /></emitter>
</scene>"#;

/// ln of both sides of Π G(x_i, x_{i+1}) / |det J| = G(x_0, x_1) |det T_1| Π_i |dω⊥_o,i / dh_i|, with the
/// index-matched factor |n_g·ω_o| / |n·ω_o| (dh = P_st dω_o at fixed ω_i: the tangent plane of the
/// direction sphere at ω_o projects onto the (s, t) plane with area factor |n·ω_o|).
fn jacobian_identity(scene: &Scene, path: &[Vertex]) -> Option<(f64, f64)> {
    let geometry = path_geometry(path);
    let eta = path_etas(scene, path);
    let lu = path_constraints(&geometry, &eta).ok()?.jacobian.factor().ok()?;
    let k = path.len() - 1;
    let g = |a: usize, b: usize| {
        let d = geometry[b].p - geometry[a].p;
        let w = d.normalize();
        (geometry[a].ng.dot(w) * geometry[b].ng.dot(w)).abs() / d.length_squared()
    };
    let lhs = (0..k).map(|i| g(i, i + 1).ln()).sum::<f64>() - lu.log_det().ln_abs;
    let mut rhs = g(0, 1).ln() + lu.transfer_from_end().determinant().abs().ln();
    for i in 1..k {
        let vc = half_vector_constraint(&geometry[i - 1], &geometry[i], &geometry[i + 1], eta[i]).ok()?;
        let cur = &geometry[i];
        let wi = (geometry[i - 1].p - cur.p).normalize();
        let wo = (geometry[i + 1].p - cur.p).normalize();
        rhs += if vc.index_matched {
            (cur.ng.dot(wo) / cur.n.dot(wo)).abs().ln()
        } else {
            let h = (wi + wo * vc.eta_rel).normalize();
            let jw = (wi.dot(h) + vc.eta_rel * wo.dot(h)).powi(2) / (vc.eta_rel.powi(2) * wo.dot(h).abs());
            (cur.ng.dot(wo).abs() * jw / cur.n.dot(h).abs()).ln()
        };
    }
    Some((lhs, rhs))
}

pub fn run(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    let scene = from_xml("index-matched", SCENE);
    let bdpt = bdpt_for(&scene);
    let seeds = seeding(&scene, &bdpt, 10, 20_000);
    let mut rng = Sampler::new(10, 0, 0);
    let paths: Vec<PathState> = (0..effort.scale(400, 4000))
        .filter_map(|_| seeds.draw(&scene, &bdpt, 10, rng.next_f64()))
        .filter(|x| x.vertices.len() == 4 && x.vertices[1].delta)
        .collect();
    report.check(paths.len() > 100, format!("only {} camera-sheet-plane-light paths", paths.len()));

    // The constraint at the sheet: unnormalised, at its solution, with an invertible Jacobian.
    let (mut matched, mut solved, mut worst_h, mut worst_identity) = (0, 0, 0.0f64, 0.0f64);
    for x in &paths {
        let Ok(c) = path_constraints(&path_geometry(&x.vertices), &path_etas(&scene, &x.vertices)) else {
            continue;
        };
        matched += c.index_matched[0] as usize;
        worst_h = worst_h.max(c.h[0].length());
        solved += c.jacobian.factor().is_ok() as usize;
        if let Some((lhs, rhs)) = jacobian_identity(&scene, &x.vertices) {
            worst_identity = worst_identity.max((lhs - rhs).abs() / (1.0 + lhs.abs()));
        }
    }
    report.measure(format!(
        "{} paths through the sheet: index-matched form {matched}×, max |H~| at the sheet {worst_h:.1e}, J \
         factorised {solved}×, product-of-Jacobians identity with factor 1: max relative error {worst_identity:.1e}",
        paths.len()
    ));
    report.check(matched == paths.len(), "the sheet's constraint must take the unnormalised form");
    // BDPT continues each ray from an origin offset along the normal by ~1e-4 of the scene scale, so the
    // stored vertices bend at the sheet by up to that much (the walk below removes it): 1e-3 is ten
    // times that, far below a wrong solution (|H~| ~ 1 for reflection).
    report.check(worst_h < 1e-3, format!("seed paths are off the sheet's solution H~ = 0 by {worst_h:e}"));
    report.check(solved == paths.len(), "J with an index-matched vertex must factorise");
    // Both sides are computed in f64 from the same geometry; 1e-6 allows for a near-singular J only. A
    // factor other than 1 (e.g. dropping |n·ω_o|, the disk measure) is off by O(1) at these angles.
    report.check(
        worst_identity < 1e-6,
        format!("f_H identity with the index-matched factor off by {worst_identity:e}"),
    );

    // The Newton walk through the sheet: target 0 there, a perturbed target on the plane.
    let settings = WalkSettings { tolerance: 1e-4, ..WalkSettings::default() };
    let (mut tried, mut converged, mut worst_line, mut iterations) = (0, 0, 0.0f64, 0);
    for x in &paths {
        let eta = path_etas(&scene, &x.vertices);
        let Ok(c) = path_constraints(&path_geometry(&x.vertices), &eta) else { continue };
        let offset = DVec2::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5) * 0.1;
        let targets = [DVec2::ZERO, c.h[1] + offset];
        tried += 1;
        let Ok(result) = walk(&scene, &x.vertices, &eta, &targets, &settings) else { continue };
        converged += 1;
        iterations += result.iterations;
        // Straight through: x_1 on the segment x_0 → x_2, relative to its length.
        let (a, b, p) =
            (result.path[0].p.as_dvec3(), result.path[2].p.as_dvec3(), result.path[1].p.as_dvec3());
        let along = (b - a).normalize();
        let off_line = ((p - a) - along * (p - a).dot(along)).length() / (b - a).length();
        worst_line = worst_line.max(off_line);
    }
    report.measure(format!(
        "walks through the sheet: {converged} of {tried} converged ({:.1} iterations), x_1 off the line x_0x_2 by ≤ \
         {worst_line:.1e} of its length",
        iterations as f64 / converged.max(1) as f64
    ));
    // Walks of ~0.05 in h on a plane from an exact start: nearly all converge (a tenth may leave the
    // view's geometry or stall); the converged ones meet |H~| < 1e-4, i.e. the kink is below ~1e-4.
    report.check(
        converged * 10 >= tried * 9,
        format!("only {converged} of {tried} walks through the sheet converged"),
    );
    report.check(worst_line < 1e-4, format!("a walked path bends at the null interface by {worst_line:e}"));

    // HSLT holds the sheet at h = 0 like any Dirac vertex: no step, no step share, no kernel factor.
    let hslt = HalfVectorMutation::new(HalfVectorParams::default());
    let held = paths
        .iter()
        .filter(|x| {
            hslt.prepare(&scene, &x.vertices, x.film)
                .is_ok_and(|p| p.held[0] && !p.held[1..].iter().any(|&h| h))
        })
        .count();
    report.measure(format!("HSLT holds the sheet (and only it) on {held} of {} paths", paths.len()));
    report.check(held == paths.len(), "HSLT must hold the null interface at h = 0 and perturb the rest");
    memlt_through_the_sheet(&scene, &paths, effort, &mut report);
    report
}

/// MEMLT holds the sheet at its (unnormalised) half vector: the factor between solid angle and h at
/// the sheet, |det C_1| |dω_o/dh| = conv(x_1 → x_2), and detailed balance of the perturbation,
/// E[R·1{valid}] = P(valid) and E[R·1{R<1}] = P(R>1) for x drawn ∝ target (tests/memlt.rs has the
/// derivation).
fn memlt_through_the_sheet(scene: &Scene, paths: &[PathState], effort: Effort, report: &mut CaseReport) {
    let mut worst_factor: f64 = 0.0;
    for x in paths {
        let v = &x.vertices;
        let g = path_geometry(v);
        let eta = path_etas(scene, v);
        let (Ok(vc), Some(j)) = (
            half_vector_constraint(&g[0], &g[1], &g[2], eta[1]),
            direction_per_half_vector(
                &g[1],
                (g[0].p - g[1].p).normalize(),
                (g[2].p - g[1].p).normalize(),
                eta[1],
            ),
        ) else {
            worst_factor = f64::INFINITY;
            continue;
        };
        let conv = v[1].convert_density(1.0, &v[2], scene) as f64;
        worst_factor = worst_factor.max((vc.c.determinant().abs() * j - conv).abs() / conv);
    }
    report
        .measure(format!("MEMLT through the sheet: |det C_1|·|dω_o/dh| vs conv off by ≤ {worst_factor:.1e}"));
    // f32 vertex positions: ~1e-4 agreement on well-conditioned vertices, as for glass (tests/memlt.rs).
    report.check(worst_factor < 2e-3, format!("the sheet's Dirac factor is off by {worst_factor:e}"));
    let bdpt = bdpt_for(scene);
    let mut memlt = ManifoldPerturbation::new(50.0, 0.1);
    balance_through_the_sheet(scene, &bdpt, &mut memlt, "MEMLT", effort, report);
    let mut hslt = HalfVectorMutation::new(HalfVectorParams::default());
    balance_through_the_sheet(scene, &bdpt, &mut hslt, "HSLT", effort, report);
}

/// Detailed balance of `mutation` on paths through the sheet drawn ∝ target: E[R·1{valid}] = P(valid)
/// and E[R·1{R<1}] = P(R>1) (tests/memlt.rs has the derivation); no proposal may be invalid.
fn balance_through_the_sheet<'a>(
    scene: &'a Scene,
    bdpt: &'a Bdpt,
    mutation: &mut dyn Mutation<PathState, PathContext<'a>>,
    name: &str,
    effort: Effort,
    report: &mut CaseReport,
) {
    let seeds = seeding(scene, bdpt, 11, 20_000);
    let mut ctx = PathContext::new(scene, bdpt);
    let mut rng = Sampler::new(11, 0, 0);
    let mut stats = MutationStats::default();
    let (mut r_valid, mut r_below, mut above, mut valid, mut invalid) =
        (Vec::new(), Vec::new(), Vec::new(), 0, 0);
    for _ in 0..effort.scale(4000, 40_000) {
        let Some(x) = seeds.draw(scene, bdpt, 11, rng.next_f64()) else { continue };
        if !(x.vertices.len() == 4 && x.vertices[1].delta) {
            continue;
        }
        let r = match mutation.propose(&x, &mut ctx, &mut rng, &mut stats) {
            Ok(p) if p.t_ratio.is_finite() && p.t_ratio >= 0.0 && p.state.contribution.is_finite() => {
                valid += 1;
                Some(target(&p.state) * p.t_ratio / target(&x))
            }
            Ok(_) => {
                invalid += 1;
                None
            }
            Err(Failure::Failed(reason)) => {
                *stats.failed.entry(reason).or_default() += 1;
                None
            }
            Err(Failure::NotApplicable) => {
                stats.not_applicable += 1;
                continue;
            }
        };
        r_valid.push(r.unwrap_or(0.0));
        r_below.push(r.filter(|&r| r < 1.0).unwrap_or(0.0));
        above.push(r.map_or(0.0, |r| if r > 1.0 { 1.0 } else { 0.0 }));
    }
    let n = r_valid.len().max(1) as f64;
    let p_valid = valid as f64 / n;
    let ((rv, rv_se), (rb, rb_se), (ab, ab_se)) = (mean_se(&r_valid), mean_se(&r_below), mean_se(&above));
    report.measure(format!(
        "{name} through the sheet: {} proposals, valid {p_valid:.3}, {invalid} invalid, failed [{}]; E[R·1valid] \
         {rv:.3}±{rv_se:.3} vs P(valid) {p_valid:.3}; E[R·1(R<1)] {rb:.3}±{rb_se:.3} vs P(R>1) {ab:.3}±{ab_se:.3}",
        r_valid.len(),
        failures(&stats)
    ));
    report.check(invalid == 0, format!("{name} produced {invalid} NaN/inf proposals"));
    report.check(
        valid * 10 > r_valid.len(),
        format!("{name} moves only {valid} of {} paths through the sheet", r_valid.len()),
    );
    // The seed pool is a finite stand-in for the target: 5 standard errors plus 2% for its resampling.
    let se = (rv_se * rv_se + p_valid * (1.0 - p_valid) / n).sqrt();
    report.check(
        (rv - p_valid).abs() <= 5.0 * se + 0.02 * p_valid,
        format!("{name}: E[R·1valid] {rv:.4} vs P(valid) {p_valid:.4}"),
    );
    let se = (rb_se * rb_se + ab_se * ab_se).sqrt();
    report.check(
        (rb - ab).abs() <= 5.0 * se + 0.02 * ab,
        format!("{name}: E[R·1(R<1)] {rb:.4} vs P(R>1) {ab:.4}"),
    );
}
