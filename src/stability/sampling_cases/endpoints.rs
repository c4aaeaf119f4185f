//! Case 9: degenerate segments and endpoints (digest §5.9) for the half-vector mutation: zero-length
//! edges and a last inner vertex converging onto the emitter must end in counted failures, never in
//! NaN; the pinhole and the point light are pinned positions; environment endpoints (no position to
//! hold) are left to other mutations; a proposal whose x_1 leaves the film is rejected.

use std::collections::BTreeMap;

use super::{bdpt_for, failures, glossy_plane_xml, seeding};
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{Failure, Mutation, MutationStats, PathContext, PathState};
use crate::sampling::Sampler;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

/// What one proposal from a doctored path ended in.
#[derive(Default)]
struct Outcomes {
    /// Proposals with a finite, non-negative ratio and a finite contribution.
    valid: usize,
    /// Proposals the chain would have to reject as NaN, infinite or negative.
    invalid: usize,
    not_applicable: usize,
    failed: BTreeMap<&'static str, usize>,
}

impl Outcomes {
    fn add(&mut self, result: Result<crate::metropolis::Proposal<PathState>, Failure>) {
        match result {
            Ok(p) => {
                let c = p.state.contribution;
                if p.t_ratio.is_finite() && p.t_ratio >= 0.0 && c.is_finite() && c.min_element() >= 0.0 {
                    self.valid += 1;
                } else {
                    self.invalid += 1;
                }
            }
            Err(Failure::NotApplicable) => self.not_applicable += 1,
            Err(Failure::Failed(reason)) => *self.failed.entry(reason).or_default() += 1,
        }
    }

    fn describe(&self) -> String {
        let failed: Vec<String> = self.failed.iter().map(|(k, v)| format!("{k} {v}")).collect();
        format!(
            "{} valid, {} invalid, {} n/a, failed [{}]",
            self.valid,
            self.invalid,
            self.not_applicable,
            failed.join(", ")
        )
    }

    fn failed_total(&self) -> usize {
        self.failed.values().sum()
    }
}

pub fn run(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    // The plane reaches past the image on every side, so x_1 can walk off the film.
    let scene = from_xml("endpoint-plane", &glossy_plane_xml(0.3, 10.0, 32, 24));
    let bdpt = bdpt_for(&scene);
    let seeds = seeding(&scene, &bdpt, 90, 20_000);
    let draws = effort.scale(400, 4000);
    let mut rng = Sampler::new(90, 0, 0);
    let starts: Vec<PathState> = (0..draws)
        .filter_map(|_| seeds.draw(&scene, &bdpt, 90, rng.next_f64()))
        .filter(|x| x.vertices.len() == 3)
        .collect();
    report.check(starts.len() > draws / 2, format!("only {} camera-plane-light seeds", starts.len()));
    let mut mutation = HalfVectorMutation::new(HalfVectorParams::default());
    let mut ctx = PathContext::new(&scene, &bdpt);
    let mut stats = MutationStats::default();

    // Zero-length edge: x_1 repeated, a four-vertex path whose middle segment has length 0.
    let mut repeated = Outcomes::default();
    for x in &starts {
        let v = &x.vertices;
        let vertices = vec![v[0], v[1], v[1], v[2]];
        let state = PathState { contribution: x.contribution, scale: x.scale, film: x.film, vertices };
        repeated.add(mutation.propose(&state, &mut ctx, &mut rng, &mut stats));
    }
    report.measure(format!("x_1 = x_2 repeated: {}", repeated.describe()));
    report.check(
        repeated.failed_total() == starts.len(),
        format!("a zero-length edge must fail every proposal: {}", repeated.describe()),
    );

    // The emitter moved onto x_1 along its normal: distance ε → 0.
    let mut collapse = Vec::new();
    for eps in [1e-1f32, 1e-3, 1e-5, 1e-7, 0.0] {
        let mut out = Outcomes::default();
        for x in &starts {
            let mut vertices = x.vertices.clone();
            vertices[2].p = vertices[1].p + vertices[1].ng * eps;
            let contribution = crate::path::PathView::whole(&vertices).contribution(&scene);
            let state = PathState { vertices, contribution, scale: 1.0, film: x.film };
            out.add(mutation.propose(&state, &mut ctx, &mut rng, &mut stats));
        }
        report.check(out.invalid == 0, format!("ε = {eps:e}: {} proposals carry NaN/inf", out.invalid));
        if eps == 0.0 {
            report.check(
                out.valid == 0 && out.failed_total() == starts.len(),
                format!("x_1 on x_k must fail every proposal: {}", out.describe()),
            );
        }
        collapse.push(format!("ε={eps:e}: {}", out.describe()));
    }
    report.measure(format!("light at ε from x_1: {}", collapse.join("; ")));

    // Pinned ends and the film boundary, with stratified steps and with the larger BSDF-only steps.
    for stratify in [true, false] {
        let mut mutation =
            HalfVectorMutation::new(HalfVectorParams { stratify, ..HalfVectorParams::default() });
        let mut stats = MutationStats::default();
        let (mut valid, mut moved_ends, mut moved_x1, mut off_film) = (0, 0, 0, 0);
        let (w, h) = (scene.film.width as f32, scene.film.height as f32);
        for x in &starts {
            let p = match mutation.propose(x, &mut ctx, &mut rng, &mut stats) {
                Ok(p) => p,
                Err(Failure::Failed(reason)) => {
                    *stats.failed.entry(reason).or_default() += 1;
                    continue;
                }
                Err(Failure::NotApplicable) => continue,
            };
            let (a, b) = (&x.vertices, &p.state.vertices);
            valid += 1;
            // Bitwise: the mutation must copy the endpoints, not recompute them.
            if a[0].p != b[0].p || a[2].p != b[2].p {
                moved_ends += 1;
            }
            moved_x1 += (a[1].p != b[1].p) as usize;
            let f = p.state.film;
            if !(f.x >= 0.0 && f.y >= 0.0 && f.x < w && f.y < h) {
                off_film += 1;
            }
        }
        let outside = stats.failed.get("outside_image").copied().unwrap_or(0);
        report.measure(format!(
            "stratified {stratify}: {valid} proposals, endpoints moved {moved_ends}×, x_1 moved {moved_x1}×, \
             rejected outside the film {outside}×, failures [{}]",
            failures(&stats)
        ));
        report.check(moved_ends == 0, format!("pinhole or point light moved in {moved_ends} proposals"));
        report.check(off_film == 0, format!("{off_film} proposals outside the film were not rejected"));
        report.check(moved_x1 * 2 > valid && valid > 0, "x_1 hardly moves: the pinning check checks little");
        if !stratify {
            // BSDF-sized steps on a plane that fills the view must leave the film now and then; if they
            // never do, the film check above was never exercised.
            report.check(outside > 0, "no proposal left the film: the boundary was not exercised");
        }
    }

    // An environment endpoint has no position to hold fixed: the mutation leaves such paths alone.
    let env_xml = glossy_plane_xml(0.3, 10.0, 32, 24).replace(
        r#"<emitter type="point"><point name="position" x="0.3" y="1.2" z="1.5" /><rgb name="intensity" value="10, 10, 10" /></emitter>"#,
        r#"<emitter type="constant"><rgb name="radiance" value="1, 1, 1" /></emitter>"#,
    );
    let env = from_xml("endpoint-env", &env_xml);
    let env_bdpt = bdpt_for(&env);
    let env_seeds = seeding(&env, &env_bdpt, 91, 4096);
    let mut env_ctx = PathContext::new(&env, &env_bdpt);
    let (mut env_paths, mut env_left_alone) = (0, 0);
    for _ in 0..effort.scale(200, 2000) {
        let Some(x) = env_seeds.draw(&env, &env_bdpt, 91, rng.next_f64()) else { continue };
        if x.vertices.len() < 3 {
            continue;
        }
        env_paths += 1;
        let rays = env_ctx.counters.rays;
        let result = mutation.propose(&x, &mut env_ctx, &mut rng, &mut stats);
        env_left_alone +=
            (matches!(result, Err(Failure::NotApplicable)) && env_ctx.counters.rays == rays) as usize;
    }
    report.measure(format!(
        "environment endpoint: {env_left_alone} of {env_paths} paths not applicable at no ray cost (gap: [C13] \
         propagates a pinned direction instead; directional lights are not in the scene format)"
    ));
    report.check(env_paths > 50 && env_left_alone == env_paths, "environment-ended paths must be left alone");
    report
}
