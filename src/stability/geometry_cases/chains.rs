//! Case 4 of digest §5: long chains (10 to 20 vertices of glossy inter-reflection in a mirror tube).
//! Block LU without pivoting (supplement Fig. 2) against a pivoted dense LU, the capped Newton walk,
//! the reversibility check re-done independently, and the cost of preparing a path.

use std::time::Instant;

use glam::DVec2;

use super::support::{
    dense, draw_paths, mul, norm, pinhole_xml, pivoted_det, relative_mismatch, target, walk_to,
};
use crate::manifold::{path_constraints, path_etas, path_geometry, WalkSettings};
use crate::metropolis::mutations::halfvector::{
    applicable, HalfVectorMutation, HalfVectorParams, REVERSIBILITY_TOLERANCE,
};
use crate::metropolis::{Failure, Mutation, MutationStats, PathContext};
use crate::sampling::Sampler;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

/// A square tube of glossy mirrors (α = 0.1) with the camera at its open end and an area light
/// closing the far end: every pixel sees the light after some number of reflections, up to ~20.
fn mirror_tube() -> crate::scene::Scene {
    let wall = |rotate: &str, translate: &str| {
        format!(
            r#"<shape type="rectangle">
    <transform name="to_world"><scale x="0.5" y="4" /><rotate x="1" angle="90" />{rotate}{translate}</transform>
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="0.1" /></bsdf>
  </shape>"#
        )
    };
    let walls = [
        wall(r#"<rotate z="1" angle="-90" />"#, r#"<translate x="0.5" z="-4" />"#),
        wall(r#"<rotate z="1" angle="90" />"#, r#"<translate x="-0.5" z="-4" />"#),
        wall("", r#"<translate y="0.5" z="-4" />"#),
        wall(r#"<rotate z="1" angle="180" />"#, r#"<translate y="-0.5" z="-4" />"#),
    ]
    .join("\n  ");
    let sensor = pinhole_xml(100.0, "0, 0, -0.1", "0, 0, -1", "0, 1, 0", (32, 32));
    from_xml(
        "mirror-tube",
        &format!(
            r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="21" /><integer name="rr_depth" value="40" /></integrator>
  {sensor}
  {walls}
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.5" /><translate z="-8" /></transform>
    <emitter type="area"><rgb name="radiance" value="20, 20, 20" /></emitter>
  </shape>
</scene>"#
        ),
    )
}

pub fn long_chains(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    let scene = mirror_tube();
    let paths = draw_paths(&scene, 41, effort.scale(6_000, 24_000), effort.scale(120, 480), |x| {
        x.vertices.len() >= 11 && applicable(&x.vertices)
    });
    let longest = paths.iter().map(|x| x.vertices.len()).max().unwrap_or(0);
    let twenty = paths.iter().filter(|x| x.vertices.len() >= 16).count();
    report.measure(format!(
        "{} paths of 11–{longest} vertices ({twenty} with ≥ 16) in a glossy mirror tube",
        paths.len()
    ));
    // The case is about k = 10…20: it needs paths there, including some beyond 15 vertices.
    report.check(
        paths.len() >= 40 && twenty >= 5,
        format!("too few long paths: {} ({twenty} ≥ 16)", paths.len()),
    );

    // (a) No-pivot block LU against nalgebra's partially pivoted dense LU: ln|det J| and the residual
    // of a solve. Pivot growth would show as lost digits in both; honest chains keep ~12 (the
    // blocktri unit tests reach κ ~ 1e10 with 1e-9), so 1e-8 is a miss by four orders at least.
    let mut rng = Sampler::from_seed(4);
    let (mut worst_det, mut worst_residual, mut compared) = (0.0f64, 0.0f64, 0usize);
    let mut prepare_time = Vec::new();
    let mutation = HalfVectorMutation::new(HalfVectorParams::default());
    for x in &paths {
        let eta = path_etas(&scene, &x.vertices);
        let Ok(c) = path_constraints(&path_geometry(&x.vertices), &eta) else { continue };
        let Ok(lu) = c.jacobian.factor() else { continue };
        let m = dense(&c.jacobian);
        worst_det = worst_det.max((lu.log_det().ln_abs - pivoted_det(m.clone()).1).abs());
        compared += 1;
        let rhs: Vec<DVec2> =
            (0..c.jacobian.len()).map(|_| DVec2::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5)).collect();
        let sol = lu.solve(&rhs);
        let flat = |v: &[DVec2]| v.iter().flat_map(|p| [p.x, p.y]).collect::<Vec<f64>>();
        let jx = mul(&m, &flat(&sol));
        let diff: Vec<f64> = jx.iter().zip(flat(&rhs)).map(|(a, b)| a - b).collect();
        let residual = norm(&diff) / norm(&flat(&rhs));
        worst_residual = worst_residual.max(residual);
        let started = Instant::now();
        let prepared = (0..20).all(|_| mutation.prepare(&scene, &x.vertices, x.film).is_ok());
        if prepared {
            prepare_time.push((x.vertices.len(), started.elapsed().as_secs_f64() / 20.0));
        }
    }
    report.measure(format!(
        "block LU vs pivoted dense LU: worst |Δ ln|det J|| {worst_det:.1e}, worst relative residual \
         {worst_residual:.1e} over {compared} paths"
    ));
    report.check(worst_det < 1e-8, format!("no-pivot LU loses the determinant: {worst_det:e}"));
    report.check(worst_residual < 1e-8, format!("no-pivot LU solve residual {worst_residual:e}"));
    // Preparing includes the ray-differential row of J⁻¹ (`inverse_row`, one O(n) solve instead of
    // the O(n²) of Fig. 1): its cost per inner vertex should not grow with the chain. Reported, not
    // judged (machine load varies).
    let per_vertex = |range: std::ops::RangeInclusive<usize>| {
        let t: Vec<f64> = prepare_time
            .iter()
            .filter(|(n, _)| range.contains(n))
            .map(|(n, t)| t / (*n - 2) as f64 * 1e6)
            .collect();
        t.iter().sum::<f64>() / t.len().max(1) as f64
    };
    report.measure(format!(
        "prepare (constraints, LU, ray differentials, steps) of {} paths: {:.2} µs per inner vertex for \
         11–15 vertices, {:.2} for 16–22",
        prepare_time.len(),
        per_vertex(11..=15),
        per_vertex(16..=22)
    ));

    // (b) One proposal from each path. Every built proposal is checked again: a careful reverse
    // walk (the mutation's settings, rays cast one at a time) from Y to X's half vectors must
    // land on X; a proposal that passes the mutation's own check but not this is a wrong accept.
    let bdpt = super::support::bdpt(&scene);
    let mut ctx = PathContext::new(&scene, &bdpt);
    let mut stats = MutationStats::default();
    let mut proposer = HalfVectorMutation::new(HalfVectorParams::default());
    let mut mrng = Sampler::new(4, 4, 4);
    let careful = WalkSettings { batch_rays: false, ..HalfVectorParams::default().walk };
    let mut forward_spread = Vec::new();
    let (mut built, mut wrong, mut nonfinite, mut iterations_max) = (0usize, 0usize, 0usize, 0usize);
    let mut failures = std::collections::BTreeMap::<&str, usize>::new();
    let rounds = effort.scale(3, 10);
    for _ in 0..rounds {
        for x in &paths {
            let before = stats.sums.get("newton_iterations").copied().unwrap_or(0.0);
            match proposer.propose(x, &mut ctx, &mut mrng, &mut stats) {
                Err(Failure::Failed(reason)) => *failures.entry(reason).or_default() += 1,
                Err(Failure::NotApplicable) => *failures.entry("not_applicable").or_default() += 1,
                Ok(p) => {
                    built += 1;
                    let used = stats.sums.get("newton_iterations").copied().unwrap_or(0.0) - before;
                    iterations_max = iterations_max.max(used as usize);
                    let r = target(&p.state) * p.t_ratio / target(x);
                    nonfinite += usize::from(!(r.is_finite() && r >= 0.0));
                    let h_of = |v: &[crate::path::Vertex]| {
                        path_constraints(&path_geometry(v), &path_etas(&scene, v)).map(|c| c.h).ok()
                    };
                    // Back from Y to h(X) must land on X, and X walked to h(Y) (a different target
                    // from the sampled one, so a different iteration) must land on Y.
                    let confirms = |from: &[crate::path::Vertex], to: &[crate::path::Vertex]| {
                        let Some(h) = h_of(to) else { return Err(f64::NAN) };
                        match walk_to(&scene, from, &h, &careful) {
                            Ok(b) => {
                                let d = relative_mismatch(to, &b.path);
                                if d <= REVERSIBILITY_TOLERANCE {
                                    Ok(())
                                } else {
                                    Err(d)
                                }
                            }
                            Err(_) => Err(f64::INFINITY),
                        }
                    };
                    // The reverse walk is the mutation's reversibility check, re-done with rays cast
                    // one by one: it must agree. The forward re-walk is not judged: with the walk's
                    // 1e-4 tolerance in h, J⁻¹ of a 20-vertex chain spreads the end points by more
                    // than 1e-3 of a segment, so it only measures that spread.
                    wrong += usize::from(confirms(&p.state.vertices, &x.vertices).is_err());
                    if let Err(d) = confirms(&x.vertices, &p.state.vertices) {
                        forward_spread.push(d);
                    }
                }
            }
        }
    }
    let proposals = rounds * paths.len();
    report.measure(format!(
        "{proposals} proposals: {built} built, failures {failures:?}, at most {iterations_max} Newton \
         iterations, {wrong} not confirmed by a careful reverse walk, {nonfinite} non-finite ratios; a \
         forward re-walk X → h(Y) fails or lands > 1e-3 from Y for {} (worst landing {:.1e})",
        forward_spread.len(),
        forward_spread.iter().copied().filter(|d| d.is_finite()).fold(0.0, f64::max)
    ));
    report.check(nonfinite == 0, format!("{nonfinite} non-finite acceptance ratios on long chains"));
    report.check(
        iterations_max <= HalfVectorParams::default().walk.max_iterations,
        format!("a walk ran {iterations_max} Newton iterations, above the cap"),
    );
    // Long glossy chains must still move now and then, or the checks above saw nothing.
    report.check(built * 20 >= proposals, format!("only {built} of {proposals} long-chain proposals built"));
    // The careful walk differs from the mutation's only in casting rays one at a time; a proposal it
    // cannot confirm was built on a walk that did not really return.
    report.check(wrong == 0, format!("{wrong} of {built} long-chain proposals not reversible"));
    report
}
