//! Case 15: f32 against f64 (digest §5.15 and 2.3). The half-vector mutation's ratio carries
//! |det J(X)| / |det J(Y)|; here the block LU behind it is redone in f32 (blocks rounded to f32, plain
//! product of the pivot determinants, as an f32 implementation would) and the same chains are run with
//! both. Divergence of the accept/reject sequences is expected; a systematic shift in mean acceptance
//! would mean det J needs more precision than f32 gives.

use glam::DMat2;

use super::{bdpt_for, mean_se, seeding, target};
use crate::manifold::{path_constraints, path_etas, path_geometry, BlockTridiagonal};
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{
    Chain, Failure, Mutation, MutationStats, PathContext, PathState, Proposal, TargetFunction,
    WeightedMutation,
};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::stability::scenes::{bundled, from_xml};
use crate::stability::{CaseReport, Effort};

/// ln |det J| by block Thomas elimination in f32; `None` when a pivot is singular or the product
/// under- or overflows f32.
fn ln_det_f32(j: &BlockTridiagonal) -> Option<f64> {
    let single = |m: DMat2| m.as_mat2();
    let mut lambda = single(j.b[0]);
    let mut det = lambda.determinant();
    for i in 1..j.len() {
        let l = single(j.a[i]) * lambda.inverse();
        lambda = single(j.b[i]) - l * single(j.c[i - 1]);
        det *= lambda.determinant();
    }
    (det.is_finite() && det != 0.0).then(|| (det.abs() as f64).ln())
}

/// ln |det J| of a path in f64 (as the mutation computes it) and in f32.
fn ln_dets(scene: &Scene, path: &[Vertex]) -> Option<(f64, Option<f64>)> {
    let c = path_constraints(&path_geometry(path), &path_etas(scene, path)).ok()?;
    let f64_det = c.jacobian.factor().ok()?.log_det().ln_abs;
    Some((f64_det, ln_det_f32(&c.jacobian)))
}

/// The f64 ratio with its determinant factor replaced by the f32 one; 0 (never accepted) where f32
/// cannot represent a determinant.
fn f32_ratio(scene: &Scene, x: &[Vertex], y: &[Vertex], t_ratio: f64) -> f64 {
    match (ln_dets(scene, x), ln_dets(scene, y)) {
        (Some((x64, Some(x32))), Some((y64, Some(y32)))) => t_ratio * ((x32 - x64) - (y32 - y64)).exp(),
        _ => 0.0,
    }
}

/// The half-vector mutation with det J in f32.
struct SinglePrecision(HalfVectorMutation);

impl<'a> Mutation<PathState, PathContext<'a>> for SinglePrecision {
    fn name(&self) -> &'static str {
        "hslt-f32"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let mut p = self.0.propose(current, ctx, rng, stats)?;
        p.t_ratio = f32_ratio(ctx.scene, &current.vertices, &p.state.vertices, p.t_ratio);
        Ok(p)
    }
}

/// Camera and point light skim a rough metal plane from the same side: wi ≈ wo, the half vector near
/// the rim of the disk, where the blocks of J are stiffest ([MNEE2]: f32 fails at grazing angles).
/// GGX: a Beckmann lobe carries nothing (e^-(tan θ/α)²) that far from the normal.
const GRAZING: &str = r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="2" /></integrator>
  <sensor type="perspective">
    <float name="fov" value="25" />
    <transform name="to_world"><lookat origin="0, -7, 0.3" target="0, 0, 0" up="0, 0, 1" /></transform>
    <film type="hdrfilm"><integer name="width" value="32" /><integer name="height" value="24" /></film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="10" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="ggx" /><float name="alpha" value="0.7" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="0.5" y="-7.5" z="0.4" /><rgb name="intensity" value="100, 100, 100" /></emitter>
</scene>"#;

pub fn run(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    report.measure(
        "f32 = block LU and pivot-determinant product in f32 on blocks rounded to f32 (the blocks' own f32 \
         arithmetic is not emulated)",
    );
    let jewelry = bundled("scenes/jewelry/scene.xml", &[("resx", "32"), ("resy", "24"), ("max_depth", "5")]);
    compare(&jewelry, "jewelry", effort, &mut report);
    let grazing = from_xml("grazing-plane", GRAZING);
    compare(&grazing, "grazing plane", effort, &mut report);
    report
}

fn compare(scene: &Scene, label: &str, effort: Effort, report: &mut CaseReport) {
    let bdpt = bdpt_for(scene);
    let seeds = seeding(scene, &bdpt, 15, 20_000);
    if seeds.candidates() == 0 {
        report.check(false, format!("{label}: the seeding pass found no light-carrying path"));
        return;
    }
    // Paired: the same proposals judged with both determinants.
    let mut mutation = HalfVectorMutation::new(HalfVectorParams::default());
    let mut ctx = PathContext::new(scene, &bdpt);
    let mut rng = Sampler::new(15, 0, 0);
    let mut stats = MutationStats::default();
    let mut radius_sum = 0.0;
    let (mut differences, mut det_errors, mut unrepresentable, mut inner) =
        (Vec::new(), Vec::new(), 0, 0usize);
    for _ in 0..effort.scale(2000, 20_000) {
        let Some(x) = seeds.draw(scene, &bdpt, 15, rng.next_f64()) else { continue };
        let Ok(p) = mutation.propose(&x, &mut ctx, &mut rng, &mut stats) else { continue };
        let r64 = target(&p.state) * p.t_ratio / target(&x);
        let r32 = target(&p.state) * f32_ratio(scene, &x.vertices, &p.state.vertices, p.t_ratio) / target(&x);
        differences.push(r32.min(1.0) - r64.min(1.0));
        for path in [&x.vertices, &p.state.vertices] {
            match ln_dets(scene, path) {
                Some((d64, Some(d32))) => det_errors.push((d32 - d64).abs()),
                _ => unrepresentable += 1,
            }
        }
        inner = inner.max(x.vertices.len() - 2);
        if let Ok(c) = path_constraints(&path_geometry(&x.vertices), &path_etas(scene, &x.vertices)) {
            radius_sum += c.h.iter().map(|h| h.length()).sum::<f64>() / c.h.len() as f64;
        }
    }
    det_errors.sort_by(f64::total_cmp);
    let pick =
        |q: f64| det_errors.get(((det_errors.len() as f64 - 1.0) * q) as usize).copied().unwrap_or(0.0);
    let (shift, shift_se) = mean_se(&differences);
    report.measure(format!(
        "{label}: {} proposals (up to {inner} inner vertices, mean |h| {:.3}): |ln det J_f32 − ln det J_f64| median {:.1e}, p99 {:.1e}, max \
         {:.1e}, f32 singular/out of range {unrepresentable}×; mean acceptance shift f32 − f64 {shift:.1e} ± {shift_se:.1e}",
        differences.len(),
        radius_sum / differences.len().max(1) as f64,
        pick(0.5),
        pick(0.99),
        pick(1.0),
    ));
    report
        .check(differences.len() > 300, format!("{label}: only {} proposals to compare", differences.len()));
    // Paired differences of the same proposals: under "no systematic difference" their mean is 0 within
    // 5 standard errors (with all differences zero the bound is 0 and so is the mean).
    report.check(
        shift.abs() <= 5.0 * shift_se,
        format!("{label}: f32 det J shifts the mean acceptance by {shift:.2e} ± {shift_se:.2e}"),
    );

    // The same chains (seed, start) with either determinant: where their accept/reject sequences part.
    let (pairs, steps) = (effort.scale(48, 256), effort.scale(150, 1000));
    let (mut first_divergence, mut acceptance_gap, mut never_diverged) = (Vec::new(), Vec::new(), 0);
    let mut started = 0;
    let mut attempts = 0;
    while started < pairs && attempts < 100 * pairs {
        attempts += 1;
        let Some(start) = seeds.draw(scene, &bdpt, 15, rng.next_f64()) else { continue };
        let chain_rng = Sampler::new(15, started as u64, 9);
        started += 1;
        let plain = HalfVectorMutation::new(HalfVectorParams::default());
        let single = SinglePrecision(HalfVectorMutation::new(HalfVectorParams::default()));
        let mut a = Chain::new(
            start.clone(),
            vec![WeightedMutation { mutation: Box::new(plain), weight: 1.0 }],
            TargetFunction::Luminance,
            chain_rng.clone(),
        );
        let mut b = Chain::new(
            start,
            vec![WeightedMutation { mutation: Box::new(single), weight: 1.0 }],
            TargetFunction::Luminance,
            chain_rng,
        );
        let (mut ctx_a, mut ctx_b) = (PathContext::new(scene, &bdpt), PathContext::new(scene, &bdpt));
        let mut diverged = None;
        for step in 0..steps {
            a.step(&mut ctx_a, &mut |_: &PathState, _| {});
            b.step(&mut ctx_b, &mut |_: &PathState, _| {});
            if diverged.is_none() && a.stats()[0].accepted != b.stats()[0].accepted {
                diverged = Some(step);
            }
        }
        match diverged {
            Some(s) => first_divergence.push(s),
            None => never_diverged += 1,
        }
        let rate = |c: &Chain<PathState, PathContext>| c.stats()[0].accepted as f64 / steps as f64;
        acceptance_gap.push(rate(&b) - rate(&a));
    }
    report.check(started == pairs, format!("{label}: only {started} chain starts"));
    first_divergence.sort_unstable();
    let median =
        first_divergence.get(first_divergence.len() / 2).map_or("none".to_string(), |s| s.to_string());
    let (gap, gap_se) = mean_se(&acceptance_gap);
    report.measure(format!(
        "{label}: {pairs} chain pairs × {steps} steps: accept/reject sequences parted in {} (median step {median}), identical in \
         {never_diverged}; acceptance f32 − f64 {gap:.1e} ± {gap_se:.1e}",
        first_divergence.len()
    ));
    // Chain pairs are independent: 5σ of the mean of the paired acceptance gaps.
    report.check(
        gap.abs() <= 5.0 * gap_se,
        format!("{label}: f32 chains accept {gap:.2e} ± {gap_se:.2e} more than f64 ones"),
    );
}
