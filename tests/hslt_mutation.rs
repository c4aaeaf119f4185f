//! The HSLT half-vector mutation (Kaplanyan et al. 2014): its ratio matches the transition densities
//! evaluated both ways, detailed balance holds statistically for paths drawn from the target, chains
//! that run only this mutation reproduce BDPT, and stiff input is rejected and counted, never NaN.

use hslt::cli::load_scene;
use hslt::manifold::{
    path_constraints, path_etas, path_geometry, path_geometry_in_chart, walk_in_chart_counting_rays,
};
use hslt::metropolis::mutations::halfvector::Chain as MovedChain;
use hslt::metropolis::mutations::halfvector::{
    applicable, relative_mismatch, walk_from, HalfVectorMutation, HalfVectorParams, TraceDirection,
    TraceStart, REVERSIBILITY_TOLERANCE,
};
use hslt::metropolis::{
    Chain, Failure, MltSettings, Mutation, MutationKind, MutationStats, PathContext, PathMlt, PathSeeds,
    PathState, TargetFunction, WeightedMutation,
};
use hslt::registry::{make_with, IntegratorKind, IntegratorSettings};
use hslt::render::{DepthLimits, RenderOptions};
use hslt::sampling::Sampler;
use hslt::scene::Scene;
use std::path::Path;
use std::sync::atomic::AtomicBool;

mod common;

use common::mlt::{bdpt, blocks, discrepancy, mean_se};

fn scene(rel: &str, defines: &[(&str, &str)]) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    load_scene(&path, defines).unwrap_or_else(|e| panic!("{rel}: {e:#}"))
}

fn target(state: &PathState) -> f64 {
    state.luminance()
}

/// ln of |det J| · Π_Dirac |dω_o/dh⊥|, the factor between the half-vector kernel and the chain's measure.
/// ln |det J| · Π_Dirac |dω_o/dh⊥| of `path` with its frames in `chart` (another path's frame chart:
/// each kernel reads the other path in its own chart).
fn ln_det_j(scene: &Scene, path: &[hslt::path::Vertex], chart: &[glam::DVec3]) -> f64 {
    let (g, eta) = (path_geometry_in_chart(path, Some(chart)), path_etas(scene, path));
    let c = path_constraints(&g, &eta).unwrap();
    let dirac = hslt::manifold::log_dirac_factor(path, &path_geometry(path), &eta).unwrap();
    c.jacobian.factor().unwrap().log_det().ln_abs + dirac
}

/// The stretch of vertices a proposal moved: from the last vertex before the first that moved to the
/// first after the last that moved (the chain's held ends).
fn moved_chain(x: &PathState, y: &PathState) -> MovedChain {
    let moved: Vec<usize> = (0..x.vertices.len()).filter(|&i| x.vertices[i].p != y.vertices[i].p).collect();
    let (first, last) = (moved[0], moved[moved.len() - 1]);
    MovedChain { start: first - 1, end: last + 1 }
}

/// Any path: the detailed-balance checks draw from the whole stationary distribution.
fn every_path(_: &PathState) -> bool {
    true
}

/// Paths through at least one Dirac vertex. HSLT keeps which vertices are Dirac, so the balance
/// identities hold on this subset of the stationary distribution too.
fn through_dirac(x: &PathState) -> bool {
    x.vertices[1..x.vertices.len() - 1].iter().any(|v| v.delta)
}

/// What many single proposals from target-distributed paths gave.
#[derive(Default)]
struct ProposalSample {
    /// Per applicable proposal: R·1{valid} − 1{valid} and R·1{R<1} − 1{R>1}, with
    /// R = target(y) T(y→x) / (target(x) T(x→y)); both have mean 0 under detailed balance.
    balance_valid: Vec<f64>,
    balance_tail: Vec<f64>,
    valid: usize,
    accepted_sum: f64,
    not_applicable: usize,
    stats: MutationStats,
    ratio_checks: usize,
    rays: u64,
}

/// Draws paths ∝ target from a seeding pass and proposes once from each.
fn sample_proposals(
    scene: &Scene,
    seed_paths: usize,
    draws: usize,
    params: HalfVectorParams,
    seed: u64,
    keep: fn(&PathState) -> bool,
) -> ProposalSample {
    let bdpt = bdpt(scene);
    let seeds = PathSeeds::run(scene, &bdpt, seed, seed_paths, &AtomicBool::new(false));
    assert!(seeds.candidates() > 100, "the seeding pass found too few paths");
    let mut mutation = HalfVectorMutation::new(params);
    let mut ctx = PathContext::new(scene, &bdpt);
    let mut rng = Sampler::new(seed, 1, 2);
    let mut out = ProposalSample::default();
    for _ in 0..draws {
        let Some(x) = seeds.draw(scene, &bdpt, seed, rng.next_f64()) else { continue };
        if !keep(&x) {
            continue;
        }
        let rays_before = ctx.counters.rays;
        let proposal = mutation.propose(&x, &mut ctx, &mut rng, &mut out.stats);
        // Every applicable proposal walks, and every walk casts rays (at least one corrector pass).
        let cast = ctx.counters.rays - rays_before;
        assert!(matches!(proposal, Err(Failure::NotApplicable)) || cast > 0, "rays were not counted");
        out.rays += cast;
        let (valid, r) = match proposal {
            Err(Failure::NotApplicable) => {
                assert!(mutation.chains(&x.vertices).is_empty());
                out.not_applicable += 1;
                continue;
            }
            Err(Failure::Failed(reason)) => {
                *out.stats.failed.entry(reason).or_insert(0) += 1;
                (false, 0.0)
            }
            Ok(p) => {
                assert!(p.t_ratio.is_finite() && p.t_ratio >= 0.0, "ratio {}", p.t_ratio);
                let y = &p.state;
                assert_eq!(y.vertices.len(), x.vertices.len());
                assert!(y.contribution.is_finite() && target(y) > 0.0);
                // The returned ratio is the densities of both directions in the area-measure form.
                if out.ratio_checks < 200 && p.t_ratio > 0.0 {
                    let chain = moved_chain(&x, y);
                    if !params.sub_chains {
                        assert_eq!(chain, MovedChain { start: 0, end: x.vertices.len() - 1 });
                    }
                    let forward = mutation.transition_log_density(scene, &x, y, chain).unwrap();
                    let backward = mutation.transition_log_density(scene, y, &x, chain).unwrap();
                    let range = chain.start..=chain.end;
                    let chart = |p: &PathState| {
                        let film = (chain.start == 0).then_some(p.film);
                        mutation.prepare_chain(scene, &p.vertices[range.clone()], film).unwrap().chart
                    };
                    let (chart_x, chart_y) = (chart(&x), chart(y));
                    let expected = backward + ln_det_j(scene, &x.vertices[range.clone()], &chart_y)
                        - forward
                        - ln_det_j(scene, &y.vertices[range.clone()], &chart_x);
                    assert!(
                        (p.t_ratio.ln() - expected).abs() < 1e-9 * (1.0 + expected.abs()),
                        "ln ratio {} but densities give {expected}",
                        p.t_ratio.ln()
                    );
                    out.ratio_checks += 1;
                }
                (true, target(y) * p.t_ratio / target(&x))
            }
        };
        out.balance_valid.push(if valid { r - 1.0 } else { 0.0 });
        out.balance_tail.push(if r < 1.0 { r } else { 0.0 } - if r > 1.0 { 1.0 } else { 0.0 });
        out.valid += valid as usize;
        out.accepted_sum += r.min(1.0);
    }
    out
}

/// Returns the proposals' summed statistics and the number of applicable proposals (for checks of
/// which walks ran).
fn check_detailed_balance(
    rel: &str,
    defines: &[(&str, &str)],
    params: HalfVectorParams,
    keep: fn(&PathState) -> bool,
) -> (MutationStats, usize) {
    let s = scene(rel, defines);
    let started = std::time::Instant::now();
    // Independent passes, each with its own seeding pass: seed draws follow an empirical
    // distribution whose heavy-tailed weights (MIS-weighted caustic strategies) repeat some paths many
    // times, so only the spread between passes is an honest standard error of the identities.
    let passes = 40;
    let mut per_pass = (Vec::new(), Vec::new());
    let mut total = ProposalSample::default();
    let mut n = 0;
    for pass in 0..passes {
        let out = sample_proposals(&s, 20_000, 6_000, params, 100 + pass, keep);
        per_pass.0.push(out.balance_valid.iter().sum::<f64>() / out.balance_valid.len() as f64);
        per_pass.1.push(out.balance_tail.iter().sum::<f64>() / out.balance_tail.len() as f64);
        n += out.balance_valid.len();
        total.valid += out.valid;
        total.accepted_sum += out.accepted_sum;
        total.not_applicable += out.not_applicable;
        total.ratio_checks += out.ratio_checks;
        total.rays += out.rays;
        total.stats.add(&out.stats);
    }
    let (bv, bv_se) = mean_se(&per_pass.0);
    let (bt, bt_se) = mean_se(&per_pass.1);
    let sums = &total.stats.sums;
    eprintln!(
        "{rel} {defines:?}: {n} applicable proposals ({} not applicable), valid {:.3}, mean acceptance {:.3}; \
         E[R 1valid] - P(valid) = {bv:.4} ± {bv_se:.4}; E[R 1(R<1)] - P(R>1) = {bt:.4} ± {bt_se:.4} \
         ({passes} passes); failures {:?}; mean Newton iterations {:.2}; mean step {:.4}; {:.0} rays per \
         proposal; {:.1} s",
        total.not_applicable,
        total.valid as f64 / n as f64,
        total.accepted_sum / n as f64,
        total.stats.failed,
        sums.get("newton_iterations").unwrap_or(&0.0) / sums.get("converged_walks").unwrap_or(&1.0),
        sums.get("step_size").unwrap_or(&0.0) / n as f64,
        total.rays as f64 / n as f64,
        started.elapsed().as_secs_f64()
    );
    assert!(n > 2000, "too few applicable paths ({n}): the test checks nothing");
    assert!(total.valid > n / 10, "only {} of {n} proposals valid", total.valid);
    assert!(total.ratio_checks > 50);
    // Under detailed balance both differences have mean 0. With 39 degrees of freedom |t| > 5 has
    // probability ~1e-5. Measured power: leaving |det J(X)| / |det J(Y)| out of the ratio moves the
    // second identity on fig15 by ten standard errors (-0.062 ± 0.006); the kernel ratio alone is
    // close to 1 at these step sizes, so its bookkeeping is checked exactly (`ratio_checks`) instead.
    assert!(bv.abs() <= 5.0 * bv_se, "E[R 1valid] - P(valid) = {bv} ± {bv_se}");
    assert!(bt.abs() <= 5.0 * bt_se, "E[R 1(R<1)] - P(R>1) = {bt} ± {bt_se}");
    (total.stats, n)
}

#[test]
fn detailed_balance_on_jewelry() {
    check_detailed_balance(
        "scenes/jewelry/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams::default(),
        every_path,
    );
}

#[test]
fn detailed_balance_on_jewelry_without_stratification() {
    // BSDF steps only (paper Sec. 6.1 without 6.2): larger moves, the same identities.
    check_detailed_balance(
        "scenes/jewelry/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams { stratify: false, ..HalfVectorParams::default() },
        every_path,
    );
}

#[test]
fn detailed_balance_on_fig15() {
    check_detailed_balance(
        "scenes/fig15/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4"), ("roughness", "0.1")],
        HalfVectorParams::default(),
        every_path,
    );
}

#[test]
fn detailed_balance_on_fig15_traced_from_the_light() {
    // Walks from the light through the rough glass cube: the reversed path's refractions use the
    // inverted relative index, so this is where a wrong reversal of eta would show.
    check_detailed_balance(
        "scenes/fig15/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4"), ("roughness", "0.1")],
        HalfVectorParams { direction: TraceDirection::Light, ..HalfVectorParams::default() },
        every_path,
    );
}

#[test]
fn detailed_balance_on_jewelry_with_sub_chains() {
    // Chains held at rough inner vertices: the proposal density carries the chain's probability at
    // X and at Y, and chains away from the camera keep the image point and use BSDF steps.
    let (stats, n) = check_detailed_balance(
        "scenes/jewelry/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams { sub_chains: true, ..HalfVectorParams::default() },
        every_path,
    );
    let share = stats.sums.get("sub_chains").unwrap_or(&0.0) / n as f64;
    assert!((0.05..0.95).contains(&share), "sub-chains were {share:.3} of the proposals");
}

#[test]
fn detailed_balance_on_fig15_with_sub_chains() {
    check_detailed_balance(
        "scenes/fig15/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4"), ("roughness", "0.1")],
        HalfVectorParams { sub_chains: true, ..HalfVectorParams::default() },
        every_path,
    );
}

const GLOSSY_CAUSTIC: &str = "scenes/glossy-caustic/scene.xml";

#[test]
fn detailed_balance_through_dirac_vertices_with_sub_chains() {
    check_detailed_balance(
        GLOSSY_CAUSTIC,
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams { sub_chains: true, ..HalfVectorParams::default() },
        through_dirac,
    );
}

#[test]
fn detailed_balance_through_dirac_vertices() {
    // The glass ball's caustic seen in the rough metal floor: camera, floor (perturbed), two Dirac
    // refractions held at h = 0, light. Only paths through Dirac vertices are drawn, so every ratio
    // carries the Dirac factor Π |dω_o/dh⊥|; leaving it out or inverting it breaks the identities.
    let (stats, n) = check_detailed_balance(
        GLOSSY_CAUSTIC,
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams::default(),
        through_dirac,
    );
    assert!(n > 2000 && stats.sums.get("converged_walks").copied().unwrap_or(0.0) > 1000.0);
}

#[test]
fn detailed_balance_on_jewelry_with_the_direction_rule() {
    // On jewelry the rule traces about a tenth of the walks from the light (measured 0.095: paths
    // whose vertex next to the light is a smoother gem or ring than the one the camera sees), so
    // both starts occur.
    // HSLT keeps every vertex on its shape and these shapes have uniform roughness, so the walk back
    // starts from the same end as the forward walk.
    let (stats, applicable) = check_detailed_balance(
        "scenes/jewelry/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams { direction: TraceDirection::Rule, ..HalfVectorParams::default() },
        every_path,
    );
    let from_light = stats.sums.get("traced_from_light").unwrap_or(&0.0) / applicable as f64;
    eprintln!("the rule traced {from_light:.3} of the walks from the light");
    assert!(
        (0.03..=0.97).contains(&from_light),
        "the rule did not use both ends: {from_light:.3} from the light"
    );
}

#[test]
fn a_walk_from_the_prepared_kernel_is_the_walk_that_evaluates_its_start() {
    // `walk_from` hands the walk what preparing X evaluated (geometry, half vectors and the factorised
    // J, `WalkStart`); without it the walk evaluates them itself. The two must be the same walk bit for
    // bit: a start from another chart or another path, or a Jacobian not of the iterate the walk steps
    // from, changes the iterates.
    let s = scene("scenes/jewelry/scene.xml", &[("resx", "64"), ("resy", "48"), ("max_depth", "5")]);
    let bdpt = bdpt(&s);
    let seeds = PathSeeds::run(&s, &bdpt, 37, 16_384, &AtomicBool::new(false));
    let params = HalfVectorParams::default();
    let mutation = HalfVectorMutation::new(params);
    let mut rng = Sampler::new(37, 0, 0);
    let (mut compared, mut converged, mut iterations) = (0, 0, 0);
    for _ in 0..6000 {
        let Some(x) = seeds.draw(&s, &bdpt, 37, rng.next_f64()) else { continue };
        if !applicable(&x.vertices) {
            continue;
        }
        let Ok(prepared) = mutation.prepare(&s, &x.vertices, x.film) else { continue };
        let targets: Option<Vec<_>> = prepared
            .steps
            .iter()
            .zip(&prepared.h)
            .zip(&prepared.held)
            .map(|((step, centre), &held)| {
                if held {
                    return Some(glam::DVec2::ZERO);
                }
                step.proposal(*centre)?.sample([rng.next_f64(), rng.next_f64()])
            })
            .collect();
        let Some(targets) = targets else { continue };
        let (mut rays_prepared, mut rays_evaluated) = (0, 0);
        let prepared_walk = walk_from(
            &s,
            &x.vertices,
            &prepared,
            &targets,
            TraceStart::Camera,
            &params.walk,
            &mut rays_prepared,
        );
        let evaluated_walk = walk_in_chart_counting_rays(
            &s,
            &x.vertices,
            &prepared.eta,
            &targets,
            Some(&prepared.chart),
            &params.walk,
            &mut rays_evaluated,
        );
        compared += 1;
        assert_eq!(rays_prepared, rays_evaluated, "the walks cast different rays");
        match (prepared_walk, evaluated_walk) {
            (Ok(a), Ok(b)) => {
                converged += 1;
                iterations += a.iterations;
                assert_eq!((a.iterations, &a.errors, &a.h), (b.iterations, &b.errors, &b.h));
                assert!(a.path.iter().zip(&b.path).all(|(u, v)| u.p == v.p), "the walks reached other paths");
            }
            (Err(a), Err(b)) => assert_eq!(a, b),
            (a, b) => panic!("one walk converged, the other did not: {:?} / {:?}", a.err(), b.err()),
        }
    }
    eprintln!("{compared} walks compared, {converged} converged, {iterations} Newton iterations among them");
    assert!(
        compared > 500 && converged > 200 && iterations > converged,
        "too few walks: {compared}, {converged}"
    );
}

fn check_light_walk_reaches_the_camera_solution(rel: &str, defines: &[(&str, &str)]) {
    // The same targets, walked from either end of random applicable paths: the half vectors
    // and |det J| of a reversed path are the same quantities (checked first, to rounding), so a walk
    // from the light must land on the solution the camera walk finds. Each walk stops within 1e-4 of
    // the targets in h (often much closer: the relative tolerance), and |dx/dh| is of the order of the
    // segment lengths, so converged pairs agree to ~1e-4 of a segment or better (measured: median
    // 2e-7 and 2e-6, 99% below 1e-4, tail to 3e-4 where J is less well conditioned). Beyond the
    // mutation's own REVERSIBILITY_TOLERANCE the two walks found distinct solutions of the same
    // targets, which curved geometry allows (measured: 1 pair in 635 on jewelry, none of 457 on
    // fig15); the reversibility check exists for them, so they are allowed but must stay rare (1%).
    let s = scene(rel, defines);
    let bdpt = bdpt(&s);
    let seeds = PathSeeds::run(&s, &bdpt, 31, 16_384, &AtomicBool::new(false));
    let params = HalfVectorParams::default();
    let mutation = HalfVectorMutation::new(params);
    let mut rng = Sampler::new(31, 0, 0);
    let (mut both, mut camera_only, mut light_only, mut neither, mut differing_walks) = (0, 0, 0, 0, 0);
    let mut worst: f64 = 0.0;
    let mut mismatches = Vec::new();
    for _ in 0..3000 {
        let Some(x) = seeds.draw(&s, &bdpt, 31, rng.next_f64()) else { continue };
        if !applicable(&x.vertices) {
            continue;
        }
        let Ok(prepared) = mutation.prepare(&s, &x.vertices, x.film) else { continue };
        let reversed: Vec<_> = x.vertices.iter().rev().copied().collect();
        let eta_rev: Vec<f64> = prepared.eta.iter().rev().copied().collect();
        let c = path_constraints(&path_geometry(&reversed), &eta_rev).unwrap();
        for (a, b) in c.h.iter().rev().zip(&prepared.h) {
            assert!((*a - *b).length() < 1e-12, "reversed half vector {a:?} vs {b:?}");
        }
        let log_det_rev = c.jacobian.factor().unwrap().log_det().ln_abs;
        assert!((log_det_rev - prepared.log_det).abs() < 1e-9 * (1.0 + prepared.log_det.abs()));
        let mut targets = Vec::new();
        for (step, centre) in prepared.steps.iter().zip(&prepared.h) {
            let Some(q) = step.proposal(*centre) else { break };
            let Some(t) = q.sample([rng.next_f64(), rng.next_f64()]) else { break };
            targets.push(t);
        }
        if targets.len() != prepared.h.len() {
            continue;
        }
        let walk = |start| walk_from(&s, &x.vertices, &prepared, &targets, start, &params.walk, &mut 0);
        match (walk(TraceStart::Camera), walk(TraceStart::Light)) {
            (Ok(cam), Ok(light)) => {
                both += 1;
                let m = relative_mismatch(&cam.path, &light.path);
                worst = worst.max(m);
                mismatches.push(m);
                differing_walks += (cam.path.iter().zip(&light.path).any(|(a, b)| a.p != b.p)) as usize;
                // The reversal must hand back the path in camera-to-light order with its endpoints.
                assert_eq!(light.path[0].p, x.vertices[0].p);
                assert_eq!(light.path.last().unwrap().p, x.vertices.last().unwrap().p);
                for (h, t) in light.h.iter().zip(&targets) {
                    assert!((*h - *t).length() <= params.walk.tolerance, "light walk h {h:?} target {t:?}");
                }
            }
            (Ok(_), Err(_)) => camera_only += 1,
            (Err(_), Ok(_)) => light_only += 1,
            (Err(_), Err(_)) => neither += 1,
        }
    }
    mismatches.sort_by(f64::total_cmp);
    let median = mismatches.get(mismatches.len() / 2).copied().unwrap_or(0.0);
    eprintln!(
        "{rel}: camera vs light walks: both converged {both} (differing {differing_walks}), camera only \
         {camera_only}, light only {light_only}, neither {neither}; relative mismatch median {median:.2e}, \
         worst {worst:.2e}, above 1e-4: {}",
        mismatches.iter().filter(|&&m| m > 1e-4).count()
    );
    assert!(both > 300, "too few walks converged both ways: {both}");
    // Had the light walk been the camera walk, every pair would be bit-identical.
    assert!(
        differing_walks > both / 2,
        "the light walk is not a different walk ({differing_walks} of {both})"
    );
    let within = |bound: f64| mismatches.iter().filter(|&&m| m <= bound).count();
    assert!(within(1e-4) * 100 >= 95 * both, "only {} of {both} pairs agree to 1e-4", within(1e-4));
    let distinct = both - within(REVERSIBILITY_TOLERANCE);
    assert!(distinct * 100 <= both, "{distinct} of {both} light walks reached another solution");
}

#[test]
fn light_traced_walk_reaches_the_camera_traced_solution() {
    // Jewelry: reflections on the rings and refractions through the gems; fig15: through the cube.
    check_light_walk_reaches_the_camera_solution(
        "scenes/jewelry/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "5")],
    );
    check_light_walk_reaches_the_camera_solution(
        "scenes/fig15/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "5"), ("roughness", "0.1")],
    );
}

fn meta<'a>(out: &'a hslt::render::RenderOutput, key: &str) -> Option<&'a str> {
    out.metadata.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

fn meta_u64(out: &hslt::render::RenderOutput, key: &str) -> u64 {
    meta(out, key).map_or(0, |v| v.parse().unwrap())
}

fn hslt_only(scene: &Scene, chains: usize, params: HalfVectorParams) -> PathMlt {
    let mut settings = MltSettings::for_technique(vec![(MutationKind::HalfVector, 1.0)]);
    settings.chains = chains;
    // The run-to-run spread of HSLT-only chains is dominated by their starting paths and b, both from
    // the seeding pass, so a larger pass buys more precision than longer chains.
    settings.seed_paths = Some(65_536);
    settings.mutation.halfvector = params;
    PathMlt::new("hslt", bdpt(scene), settings)
}

#[test]
fn the_tracing_direction_is_recorded_and_followed() {
    // What `--hslt-direction` sets reaches the mutation: the metadata names it, and the share of
    // walks traced from the light is 0, 1, or in between for the rule (jewelry: about a tenth).
    let s = scene("scenes/jewelry/scene.xml", &[("resx", "32"), ("resy", "24"), ("max_depth", "4")]);
    for direction in TraceDirection::ALL {
        assert_eq!(TraceDirection::parse(direction.name()), Ok(direction));
        let integrator = hslt_only(&s, 256, HalfVectorParams { direction, ..HalfVectorParams::default() });
        let options = RenderOptions { spp: Some(8), seed: 5, ..Default::default() };
        let out = hslt::render::Integrator::render(&integrator, &s, &options, &AtomicBool::new(false));
        assert_eq!(meta(&out, "hslt.mlt.hslt.direction"), Some(direction.name()));
        let walks: f64 = meta(&out, "hslt.mlt.hslt.mean.converged_walks").unwrap().parse().unwrap();
        let from_light: f64 =
            meta(&out, "hslt.mlt.hslt.mean.traced_from_light").map_or(0.0, |v| v.parse().unwrap());
        eprintln!(
            "{}: {from_light:.3} of the proposals traced from the light ({walks:.3} converged)",
            direction.name()
        );
        // Means are per applicable proposal; each one that survives preparing X (all but a degenerate
        // few per thousand) counts its start.
        match direction {
            TraceDirection::Camera => assert_eq!(from_light, 0.0),
            TraceDirection::Light => assert!(from_light > 0.99 && from_light <= 1.0, "{from_light}"),
            TraceDirection::Rule => assert!(from_light > 0.01 && from_light < 0.99, "{from_light}"),
        }
    }
    assert!(TraceDirection::parse("sideways").is_err());
}

fn check_against_bdpt(rel: &str, defines: &[(&str, &str)], params: HalfVectorParams) {
    // Chains that start stationary (seeds drawn ∝ target) and run only the half-vector mutation keep
    // every recorded state distributed as the target, so their image is unbiased even though HSLT
    // alone is not ergodic. Six independent HSLT runs against six independent BDPT runs at 32 × 24
    // (48 blocks of 4 × 4): the discrepancy statistic has mean ~1 and a spread of ~0.3 under the
    // null, so 2.5 is about five standard deviations; the same statistic must see a 10% scale error.
    let s = scene(rel, defines);
    let started = std::time::Instant::now();
    let (mut proposed, mut applicable_count, mut accepted, mut invalid) = (0, 0, 0, 0);
    let mut failed = std::collections::BTreeMap::<String, u64>::new();
    let mlt: Vec<Vec<f64>> = (0..8)
        .map(|seed| {
            let integrator = hslt_only(&s, 8192, params);
            let options = RenderOptions { spp: Some(128), seed: 40 + seed, ..Default::default() };
            let out = hslt::render::Integrator::render(&integrator, &s, &options, &AtomicBool::new(false));
            let img = out.film.to_image();
            assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0));
            assert_eq!(out.stats.invalid_samples, 0);
            let n = meta_u64(&out, "hslt.mlt.hslt.proposed");
            proposed += n;
            applicable_count += n - meta_u64(&out, "hslt.mlt.hslt.not_applicable");
            accepted += meta_u64(&out, "hslt.mlt.hslt.accepted");
            invalid += meta_u64(&out, "hslt.mlt.hslt.rejected_invalid");
            for (k, v) in &out.metadata {
                if let Some(reason) = k.strip_prefix("hslt.mlt.hslt.failed.") {
                    *failed.entry(reason.to_string()).or_default() += v.parse::<u64>().unwrap();
                }
            }
            blocks(&img)
        })
        .collect();
    let limits = DepthLimits { max_depth: s.integrator.max_depth, rr_depth: s.integrator.rr_depth };
    let settings = IntegratorSettings::new(limits, s.integrator.hide_emitters);
    let bdpt_runs: Vec<Vec<f64>> = (0..8)
        .map(|seed| {
            let options = RenderOptions { spp: Some(128), seed: 400 + seed, ..Default::default() };
            let out =
                make_with(IntegratorKind::Bdpt, &settings).render(&s, &options, &AtomicBool::new(false));
            blocks(&out.film.to_image())
        })
        .collect();
    let d = discrepancy(&mlt, &bdpt_runs);
    let scaled: Vec<Vec<f64>> = mlt.iter().map(|r| r.iter().map(|v| v * 1.1).collect()).collect();
    let d_scaled = discrepancy(&scaled, &bdpt_runs);
    let flux = |runs: &[Vec<f64>]| mean_se(&runs.iter().map(|r| r.iter().sum::<f64>()).collect::<Vec<_>>());
    let ((fm, fm_se), (fb, fb_se)) = (flux(&mlt), flux(&bdpt_runs));
    eprintln!(
        "{rel} {defines:?} HSLT-only vs BDPT: discrepancy {d:.3} (scaled by 1.1: {d_scaled:.3}); flux {fm:.4}±{fm_se:.4} \
         vs {fb:.4}±{fb_se:.4}; {proposed} proposals, {applicable_count} applicable, acceptance among \
         applicable {:.3}, failures {failed:?}; {:.1} s",
        accepted as f64 / applicable_count as f64,
        started.elapsed().as_secs_f64()
    );
    assert_eq!(invalid, 0, "no proposal may be invalid (NaN or negative)");
    assert!(accepted > applicable_count / 10, "the mutation hardly ever moves: the test checks little");
    assert!(d < 2.5, "HSLT-only chains differ from BDPT: discrepancy {d:.3}");
    assert!(d_scaled > 2.5, "the comparison cannot see a 10% error ({d_scaled:.3})");
    let flux_tol = 5.0 * (fm_se * fm_se + fb_se * fb_se).sqrt();
    assert!((fm - fb).abs() <= flux_tol, "total flux {fm:.4} vs BDPT {fb:.4} (± {flux_tol:.4})");
}

#[test]
fn hslt_only_chains_reproduce_bdpt_on_the_glossy_caustic() {
    check_against_bdpt(
        GLOSSY_CAUSTIC,
        &[("resx", "32"), ("resy", "24"), ("max_depth", "4")],
        HalfVectorParams::default(),
    );
}

#[test]
fn hslt_only_chains_reproduce_bdpt_on_jewelry() {
    check_against_bdpt(
        "scenes/jewelry/scene.xml",
        &[("resx", "32"), ("resy", "24"), ("max_depth", "4")],
        HalfVectorParams::default(),
    );
}

#[test]
fn hslt_only_chains_with_sub_chains_reproduce_bdpt_on_jewelry() {
    check_against_bdpt(
        "scenes/jewelry/scene.xml",
        &[("resx", "32"), ("resy", "24"), ("max_depth", "4")],
        HalfVectorParams { sub_chains: true, ..HalfVectorParams::default() },
    );
}

#[test]
fn hslt_only_chains_reproduce_bdpt_on_fig15() {
    check_against_bdpt(
        "scenes/fig15/scene.xml",
        &[("resx", "32"), ("resy", "24"), ("max_depth", "4"), ("roughness", "0.1")],
        HalfVectorParams::default(),
    );
}

/// For one seeding pass: HSLT-only chains and motionless chains from the same starts (drawn ∝ target
/// among applicable paths), each recording the film block of every state it records, weighted as
/// the chain records it. Returns per block (HSLT − motionless) / (chains · steps): the mass the
/// mutation moved into the block. Both chains start from the target restricted to the paths HSLT
/// applies to, which HSLT maps onto itself, so the expected shift is 0; sharing the starts removes
/// their noise, which dominates any image of chains this short.
fn block_shift(scene: &Scene, seed: u64, chains: usize, steps: usize, params: HalfVectorParams) -> Vec<f64> {
    const GRID: (usize, usize) = (8, 6);
    let bdpt = bdpt(scene);
    let seeds = PathSeeds::run(scene, &bdpt, seed, 20_000, &AtomicBool::new(false));
    let mut rng = Sampler::new(seed, 7, 7);
    let (w, h) = (scene.film.width as f32, scene.film.height as f32);
    let block = |state: &PathState| {
        let bx = ((state.film.x / w * GRID.0 as f32) as usize).min(GRID.0 - 1);
        let by = ((state.film.y / h * GRID.1 as f32) as usize).min(GRID.1 - 1);
        by * GRID.0 + bx
    };
    let mut shift = vec![0.0; GRID.0 * GRID.1];
    let mut started = 0;
    while started < chains {
        let Some(start) = seeds.draw(scene, &bdpt, seed, rng.next_f64()) else { continue };
        if !applicable(&start.vertices) {
            continue;
        }
        started += 1;
        let start_target = target(&start);
        // A motionless chain records its start with weight 1 / target at every step.
        shift[block(&start)] -= steps as f64;
        let mutation = Box::new(HalfVectorMutation::new(params));
        let mut chain = Chain::new(
            start,
            vec![WeightedMutation { mutation, weight: 1.0 }],
            TargetFunction::Luminance,
            Sampler::new(seed, started as u64, 3),
        );
        let mut ctx = PathContext::new(scene, &bdpt);
        let mut record = |state: &PathState, weight: f64| shift[block(state)] += weight * target(state);
        for _ in 0..steps {
            chain.step(&mut ctx, &mut record);
        }
        assert!(start_target > 0.0);
    }
    shift.iter().map(|v| v / (chains * steps) as f64).collect()
}

fn check_block_shift(rel: &str, defines: &[(&str, &str)], params: HalfVectorParams) {
    let s = scene(rel, defines);
    let started = std::time::Instant::now();
    let runs: Vec<Vec<f64>> = (0..16).map(|r| block_shift(&s, 300 + r, 600, 40, params)).collect();
    let mut t2 = Vec::new();
    let mut moved = 0.0;
    for j in 0..runs[0].len() {
        let col: Vec<f64> = runs.iter().map(|r| r[j]).collect();
        let (m, se) = mean_se(&col);
        moved += col.iter().map(|v| v.abs()).sum::<f64>() / col.len() as f64;
        if se > 0.0 {
            t2.push((m / se).powi(2));
        }
    }
    let mean_t2 = t2.iter().sum::<f64>() / t2.len() as f64;
    eprintln!(
        "{rel} {defines:?}: mean t² of the HSLT block shift {mean_t2:.3} over {} blocks (16 runs); mass moved \
         between blocks {moved:.4}; {:.1} s",
        t2.len(),
        started.elapsed().as_secs_f64()
    );
    assert!(t2.len() >= 10 && moved > 1e-3, "the chains hardly move: the test checks nothing");
    // Each t² of 16 runs follows F(1, 15): mean 1.15, variance 3.4, so the mean over n blocks has a
    // standard deviation of about sqrt(3.4 / n) (blocks are nearly independent: mass moves a few
    // pixels); the bound is five of them above the mean. Measured power: without |det J(X)| /
    // |det J(Y)| in the ratio the statistic is 3.0 (jewelry) and 5.9 (fig15), without the kernel ratio
    // 4.5 on jewelry; the correct ratio gives 1.3 and 0.9.
    let bound = 1.15 + 5.0 * (3.4 / t2.len() as f64).sqrt();
    assert!(mean_t2 < bound, "HSLT moves mass between film blocks: mean t² {mean_t2:.3} (bound {bound:.2})");
}

#[test]
fn hslt_moves_no_mass_on_fig15() {
    check_block_shift(
        "scenes/fig15/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4"), ("roughness", "0.1")],
        HalfVectorParams::default(),
    );
}

#[test]
fn hslt_moves_no_mass_on_fig15_traced_from_the_light() {
    // The strongest of the statistical checks (it sees a missing |det J| ratio at 5.9 against 0.9) on
    // walks through the rough glass cube traced from the light.
    check_block_shift(
        "scenes/fig15/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4"), ("roughness", "0.1")],
        HalfVectorParams { direction: TraceDirection::Light, ..HalfVectorParams::default() },
    );
}

#[test]
fn hslt_moves_no_mass_on_jewelry() {
    check_block_shift(
        "scenes/jewelry/scene.xml",
        &[("resx", "64"), ("resy", "48"), ("max_depth", "4")],
        HalfVectorParams { stratify: false, ..HalfVectorParams::default() },
    );
}

/// Runs `chains` HSLT-only chains of `steps` mutations from seed draws and checks every recorded
/// state and weight is finite; returns the summed statistics.
fn run_chains(scene: &Scene, chains: usize, steps: usize, params: HalfVectorParams) -> MutationStats {
    let bdpt = bdpt(scene);
    let seeds = PathSeeds::run(scene, &bdpt, 9, 16_384, &AtomicBool::new(false));
    assert!(seeds.candidates() > 0, "the scene carries no light");
    let mut total = MutationStats::default();
    let mut rng = Sampler::new(9, 0, 0);
    for c in 0..chains {
        let Some(start) = seeds.draw(scene, &bdpt, 9, rng.next_f64()) else { continue };
        let mutation = Box::new(HalfVectorMutation::new(params));
        let mut chain = Chain::new(
            start,
            vec![WeightedMutation { mutation, weight: 1.0 }],
            TargetFunction::Luminance,
            Sampler::new(9, c as u64, 1),
        );
        let mut ctx = PathContext::new(scene, &bdpt);
        let mut record = |state: &PathState, weight: f64| {
            assert!(weight.is_finite() && weight > 0.0, "recorded weight {weight}");
            assert!(state.contribution.is_finite() && state.contribution.min_element() >= 0.0);
            assert!(state.film.is_finite());
        };
        for _ in 0..steps {
            chain.step(&mut ctx, &mut record);
        }
        total.add(&chain.stats()[0]);
    }
    total
}

fn describe(stats: &MutationStats) -> String {
    let applied = stats.proposed - stats.not_applicable;
    format!(
        "{} proposed, {applied} applicable, acceptance among applicable {:.3}, rejected_zero {}, \
         rejected_invalid {}, failures {:?}, mean Newton iterations {:.2}, mean step {:.4}",
        stats.proposed,
        stats.accepted as f64 / applied.max(1) as f64,
        stats.rejected_zero,
        stats.rejected_invalid,
        stats.failed,
        stats.sums.get("newton_iterations").unwrap_or(&0.0)
            / stats.sums.get("converged_walks").unwrap_or(&1.0),
        stats.sums.get("step_size").unwrap_or(&0.0) / applied.max(1) as f64
    )
}

fn scene_from_xml(name: &str, xml: &str) -> Scene {
    let path = std::env::temp_dir().join(format!("hslt-mutation-{name}-{}.xml", std::process::id()));
    std::fs::write(&path, xml).unwrap();
    let scene = load_scene(&path, &[]).unwrap();
    std::fs::remove_file(&path).ok();
    scene
}

#[test]
fn near_specular_vertices_are_rejected_and_counted_never_nan() {
    // α = 1e-3: steps of 1e-3 in h, Phong exponents of 2·10⁶; the walk's 1e-4 tolerance is then a
    // tenth of a step, so failures and rejections are expected, invalid values never.
    let s = scene(
        "scenes/jewelry/scene.xml",
        &[
            ("resx", "32"),
            ("resy", "24"),
            ("max_depth", "4"),
            ("ring_roughness", "0.001"),
            ("gem_roughness", "0.001"),
        ],
    );
    let stats = run_chains(&s, 256, 40, HalfVectorParams::default());
    eprintln!("near-specular jewelry: {}", describe(&stats));
    assert!(
        stats.proposed > stats.not_applicable + 500,
        "too few applicable proposals: {}",
        describe(&stats)
    );
    assert_eq!(stats.rejected_invalid, 0);
    assert_eq!(
        stats.proposed,
        stats.accepted
            + stats.rejected
            + stats.rejected_zero
            + stats.rejected_invalid
            + stats.not_applicable
            + stats.failed_total()
    );
}

#[test]
fn grazing_paths_are_rejected_and_counted_never_nan() {
    // Camera and light skim a rough metal plane from the same side, so wi ≈ wo and the half vector
    // lies near the rim of the disk (|h⊥| → 1) where the Möbius map and the Jacobians are stiffest.
    let s = scene_from_xml(
        "grazing",
        r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="3" /></integrator>
  <sensor type="perspective">
    <float name="fov" value="20" />
    <transform name="to_world"><lookat origin="0, -6, 0.25" target="0, 0, 0" up="0, 0, 1" /></transform>
    <film type="hdrfilm"><integer name="width" value="32" /><integer name="height" value="24" /></film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="10" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="ggx" /><float name="alpha" value="0.8" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.3" /><rotate x="1" angle="-80" /><translate x="0.4" y="-6.5" z="0.35" /></transform>
    <emitter type="area"><rgb name="radiance" value="50, 50, 50" /></emitter>
  </shape>
</scene>"#,
    );
    let bdpt = bdpt(&s);
    let seeds = PathSeeds::run(&s, &bdpt, 9, 4096, &AtomicBool::new(false));
    let mut rng = Sampler::new(1, 0, 0);
    let radii: Vec<f64> = (0..200)
        .filter_map(|_| seeds.draw(&s, &bdpt, 9, rng.next_f64()))
        .filter(|x| x.vertices.len() == 3)
        .map(|x| {
            let c = path_constraints(&path_geometry(&x.vertices), &path_etas(&s, &x.vertices)).unwrap();
            c.h[0].length()
        })
        .collect();
    let (mean_radius, _) = mean_se(&radii);
    assert!(mean_radius > 0.9, "the paths are not grazing: mean |h| {mean_radius}");
    for stratify in [true, false] {
        let params = HalfVectorParams { stratify, ..HalfVectorParams::default() };
        let stats = run_chains(&s, 256, 40, params);
        eprintln!("grazing plane (mean |h| {mean_radius:.3}, stratified {stratify}): {}", describe(&stats));
        assert!(
            stats.proposed > stats.not_applicable + 500,
            "too few applicable proposals: {}",
            describe(&stats)
        );
        assert_eq!(stats.rejected_invalid, 0);
    }
}

#[test]
fn paths_it_does_not_apply_to_are_left_alone() {
    // fig15 seeds include all-diffuse paths (ground and sphere) and glossy ones, the Cornell box paths
    // where the camera sees the light, and the caustic scene paths through a smooth glass ball (Dirac
    // vertices, but no glossy vertex to perturb).
    let mut checked = [0usize; 3];
    for (rel, defines) in [
        ("scenes/fig15/scene.xml", vec![("resx", "32"), ("resy", "24"), ("max_depth", "4")]),
        ("scenes/caustic/scene.xml", vec![("resx", "32"), ("resy", "32")]),
        ("scenes/cornell-box/scene.xml", vec![("resx", "32"), ("resy", "32")]),
    ] {
        let s = scene(rel, &defines);
        let bdpt = bdpt(&s);
        let seeds = PathSeeds::run(&s, &bdpt, 3, 16_384, &AtomicBool::new(false));
        let mut mutation = HalfVectorMutation::new(HalfVectorParams::default());
        let mut ctx = PathContext::new(&s, &bdpt);
        let mut rng = Sampler::new(3, 0, 0);
        for _ in 0..3000 {
            let Some(x) = seeds.draw(&s, &bdpt, 3, rng.next_f64()) else { continue };
            let inner = &x.vertices[1..x.vertices.len() - 1];
            let kind = if inner.is_empty() {
                0
            } else if inner.iter().any(|v| v.delta)
                && !inner
                    .iter()
                    .any(|v| !v.delta && matches!(v.class, hslt::path::ScatterClass::Glossy { .. }))
            {
                1
            } else if inner.iter().all(|v| matches!(v.class, hslt::path::ScatterClass::Diffuse)) {
                2
            } else {
                continue;
            };
            let mut stats = MutationStats::default();
            let rays = ctx.counters.rays;
            let result = mutation.propose(&x, &mut ctx, &mut rng, &mut stats);
            assert!(matches!(result, Err(Failure::NotApplicable)), "{rel}: {:?}", result.map(|p| p.t_ratio));
            assert_eq!(ctx.counters.rays, rays, "a path it does not apply to costs no rays");
            assert!(stats.sums.is_empty());
            checked[kind] += 1;
        }
    }
    eprintln!(
        "not applicable: {} two-vertex, {} Dirac, {} all-diffuse paths",
        checked[0], checked[1], checked[2]
    );
    assert!(checked.iter().all(|&n| n > 10), "cases not all exercised: {checked:?}");
}

/// The product-of-Jacobians form of f_H's geometric part (digest 2.4): Π G(x_i, x_{i+1}) / |det J| =
/// G(x_0, x_1) |det T_1| Π_i |n_g·ω_o| |dω_o/dω_H| / |n·H|, with T_1 = ∂x_1/∂x_k, the per-vertex
/// factor the projected solid angle per unit projected half vector (Walter et al. 2007 for
/// refraction), both in f64 from the same local geometry.
fn product_of_jacobians(scene: &Scene, path: &[hslt::path::Vertex]) -> Option<(f64, f64)> {
    use hslt::manifold::half_vector_constraint;
    let geometry = path_geometry(path);
    let eta = path_etas(scene, path);
    let constraints = path_constraints(&geometry, &eta).ok()?;
    let lu = constraints.jacobian.factor().ok()?;
    let k = path.len() - 1;
    let g = |a: usize, b: usize| {
        let d = geometry[b].p - geometry[a].p;
        let w = d.normalize();
        (geometry[a].ng.dot(w) * geometry[b].ng.dot(w)).abs() / d.length_squared()
    };
    let ln_lhs = (0..k).map(|i| g(i, i + 1).ln()).sum::<f64>() - lu.log_det().ln_abs;
    let mut ln_rhs = g(0, 1).ln() + lu.transfer_from_end().determinant().abs().ln();
    for i in 1..k {
        let vc = half_vector_constraint(&geometry[i - 1], &geometry[i], &geometry[i + 1], eta[i]).ok()?;
        if vc.index_matched {
            return None;
        }
        let cur = &geometry[i];
        let wi = (geometry[i - 1].p - cur.p).normalize();
        let wo = (geometry[i + 1].p - cur.p).normalize();
        let h = (wi + wo * vc.eta_rel).normalize();
        let jacobian_w =
            (wi.dot(h) + vc.eta_rel * wo.dot(h)).powi(2) / (vc.eta_rel.powi(2) * wo.dot(h).abs());
        ln_rhs += (cur.ng.dot(wo).abs() * jacobian_w / cur.n.dot(h).abs()).ln();
    }
    Some((ln_lhs, ln_rhs))
}

#[test]
fn half_vector_measure_matches_the_product_of_jacobians() {
    // Random glossy paths (reflections on the rings, refractions through the gems and the cube) of
    // two to four inner vertices; both sides are computed in f64 from the same geometry, so they
    // agree to rounding unless J is near-singular, which the 1e-6 relative bound allows for.
    let mut checked = std::collections::BTreeMap::<usize, usize>::new();
    for (rel, defines) in [
        ("scenes/jewelry/scene.xml", vec![("resx", "32"), ("resy", "24"), ("max_depth", "5")]),
        (
            "scenes/fig15/scene.xml",
            vec![("resx", "32"), ("resy", "24"), ("max_depth", "5"), ("roughness", "0.1")],
        ),
    ] {
        let s = scene(rel, &defines);
        let bdpt = bdpt(&s);
        let seeds = PathSeeds::run(&s, &bdpt, 21, 16_384, &AtomicBool::new(false));
        let mut rng = Sampler::new(21, 0, 0);
        for _ in 0..4000 {
            let Some(x) = seeds.draw(&s, &bdpt, 21, rng.next_f64()) else { continue };
            if !applicable(&x.vertices) {
                continue;
            }
            let Some((lhs, rhs)) = product_of_jacobians(&s, &x.vertices) else { continue };
            assert!(
                (lhs - rhs).abs() < 1e-6 * (1.0 + lhs.abs()),
                "{rel}: ln(Π G / |det J|) = {lhs}, product of Jacobians {rhs}, {} vertices",
                x.vertices.len()
            );
            *checked.entry(x.vertices.len() - 2).or_default() += 1;
        }
    }
    eprintln!("f_H identity checked on paths with (inner vertices: count) {checked:?}");
    assert!(checked.keys().any(|&n| n >= 2) && checked.values().sum::<usize>() > 500, "{checked:?}");
}

/// Measurement helper, not a check: acceptance and failures against the step scale, with and without
/// stratification. `cargo test --test hslt_mutation -- --ignored acceptance_table --nocapture`.
#[test]
#[ignore]
fn acceptance_table() {
    for (rel, defines) in [
        ("scenes/jewelry/scene.xml", vec![("resx", "64"), ("resy", "48"), ("max_depth", "4")]),
        ("scenes/fig15/scene.xml", vec![("resx", "64"), ("resy", "48"), ("max_depth", "4")]),
        (
            "scenes/fig15/scene.xml",
            vec![("resx", "64"), ("resy", "48"), ("max_depth", "4"), ("roughness", "0.1")],
        ),
    ] {
        let s = scene(rel, &defines);
        for stratify in [true, false] {
            for step_scale in [0.5, 1.0, 2.0, 4.0] {
                let params = HalfVectorParams { step_scale, stratify, ..HalfVectorParams::default() };
                let out = sample_proposals(&s, 40_000, 8_000, params, 77, every_path);
                let n = out.balance_valid.len();
                let sums = &out.stats.sums;
                println!(
                    "{rel} {:?} stratify {stratify} scale {step_scale}: acceptance {:.3}, valid {:.3}, \
                     Newton {:.2}, step {:.4}, rays/proposal {:.0}, failures {:?}",
                    &defines[3..],
                    out.accepted_sum / n as f64,
                    out.valid as f64 / n as f64,
                    sums.get("newton_iterations").unwrap_or(&0.0)
                        / sums.get("converged_walks").unwrap_or(&1.0),
                    sums.get("step_size").unwrap_or(&0.0) / n as f64,
                    out.rays as f64 / n as f64,
                    out.stats.failed
                );
            }
        }
    }
}

/// Measurement helper, not a check: the same proposal (same start, same targets) walked from either
/// end, and what a per-path choice of the end could gain: the smoother-end rule (`Rule`), the
/// shorter-end-segment rule and its opposite, and the best of both per proposal (an upper bound for
/// any rule, which cannot see the targets).
/// `cargo test --test hslt_mutation -- --ignored direction_table --nocapture`.
#[test]
#[ignore]
fn direction_table() {
    for (rel, defines) in [
        ("scenes/jewelry/scene.xml", vec![("resx", "128"), ("resy", "96")]),
        ("scenes/fig17/scene.xml", vec![("resx", "128"), ("resy", "96")]),
        ("scenes/fig15/scene.xml", vec![("resx", "128"), ("resy", "96")]),
    ] {
        let s = scene(rel, &defines);
        let bdpt = bdpt(&s);
        let seeds = PathSeeds::run(&s, &bdpt, 55, 65_536, &AtomicBool::new(false));
        let mut ctx = PathContext::new(&s, &bdpt);
        let mut draw = Sampler::new(55, 0, 0);
        let mut mutations: Vec<HalfVectorMutation> = [TraceDirection::Camera, TraceDirection::Light]
            .into_iter()
            .map(|direction| {
                HalfVectorMutation::new(HalfVectorParams { direction, ..HalfVectorParams::default() })
            })
            .collect();
        // Sums of min(1, R) for: camera, light, smoother end, shorter end segment, longer, best of both.
        let mut sums = [0.0f64; 6];
        let mut n = 0usize;
        for i in 0..20_000u64 {
            let Some(x) = seeds.draw(&s, &bdpt, 55, draw.next_f64()) else { continue };
            if !applicable(&x.vertices) {
                continue;
            }
            n += 1;
            let mut acceptance = [0.0f64; 2];
            for (a, mutation) in acceptance.iter_mut().zip(&mut mutations) {
                // The same stream for both ends: the targets are drawn before the walk.
                let mut rng = Sampler::new(56, i, 0);
                let mut stats = MutationStats::default();
                if let Ok(p) = mutation.propose(&x, &mut ctx, &mut rng, &mut stats) {
                    let r = target(&p.state) * p.t_ratio / target(&x);
                    *a = if r.is_finite() { r.min(1.0) } else { 0.0 };
                }
            }
            let v = &x.vertices;
            let k = v.len() - 1;
            let (first, last) = ((v[1].p - v[0].p).length(), (v[k].p - v[k - 1].p).length());
            let smoother_light = TraceDirection::Rule.start_for(v) == TraceStart::Light;
            let pick = |light: bool| acceptance[light as usize];
            sums[0] += acceptance[0];
            sums[1] += acceptance[1];
            sums[2] += pick(smoother_light);
            sums[3] += pick(last < first);
            sums[4] += pick(last > first);
            sums[5] += acceptance[0].max(acceptance[1]);
        }
        let m = sums.map(|v| v / n.max(1) as f64);
        println!(
            "{rel}: {n} proposals; E[min(1,R)] camera {:.4}, light {:.4}, smoother end {:.4}, shorter end \
             segment {:.4}, longer {:.4}, best of both {:.4}",
            m[0], m[1], m[2], m[3], m[4], m[5]
        );
    }
}
