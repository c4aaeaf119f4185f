//! The path-space chain state and its seeding: every BDPT strategy rebuilt as a whole path
//! (`Contribution::path`) evaluates, through `PathState`, to the contribution BDPT weighted — so chains
//! start on the paths BDPT found, with the f the mutations will score — and seed draws follow the
//! weighted contributions.

use hslt::cli::load_scene;
use hslt::integrators::Bdpt;
use hslt::metropolis::mlt::DEFAULT_PATH_CHAINS;
use hslt::metropolis::pssmlt::PssContext;
use hslt::metropolis::{MltSettings, MutationKind, PathMlt, PathSeeds, PathState, Pssmlt, TargetFunction};
use hslt::path::{mis_weight, MisHeuristic, PathView, Vertex};
use hslt::render::{DepthLimits, Integrator, RenderOptions};
use hslt::sampling::Sampler;
use hslt::scene::Scene;
use hslt::spectrum::luminance;
use std::path::Path;
use std::sync::atomic::AtomicBool;

fn scene(rel: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    load_scene(&path, &[("resx", "32"), ("resy", "32")]).unwrap_or_else(|e| panic!("{rel}: {e:#}"))
}

fn bdpt(scene: &Scene) -> Bdpt {
    let limits = DepthLimits::of_scene(scene);
    Bdpt::new(limits, scene.integrator.hide_emitters)
}

/// Density of strategy t on a path, with Dirac lobes contributing their lobe probability (the
/// convention of path-space MLT), computed from scratch on the rebuilt path.
fn strategy_density(scene: &Scene, path: &[Vertex], t: usize) -> f64 {
    let view = PathView::whole(path);
    let pdfs = view.pdfs(scene);
    PathView::strategy_pdf(&pdfs, t)
}

/// As `strategy_density`, with a direction sampled through a Dirac lobe given its lobe probability.
fn dirac_strategy_density(scene: &Scene, path: &[Vertex], t: usize) -> f64 {
    use hslt::bsdf::TransportMode;
    let n = path.len();
    let mut p = 1.0f64;
    let dirac = |i: usize, from: usize, to: usize, mode| {
        let v = &path[i];
        let (_, prob) =
            v.dirac_lobe(scene, v.direction_to(&path[from]), v.direction_to(&path[to]), mode).unwrap();
        v.convert_density(prob, &path[to], scene) as f64
    };
    for i in 1..t {
        p *= if i >= 2 && path[i - 1].delta {
            dirac(i - 1, i - 2, i, TransportMode::Radiance)
        } else {
            let prev = (i >= 2).then(|| &path[i - 2]);
            PathView::density(scene, prev, &path[i - 1], &path[i], TransportMode::Radiance) as f64
        };
    }
    p *= path[n - 1].pdf_light_origin(scene) as f64;
    for i in (t..n - 1).rev() {
        p *= if i + 2 < n && path[i + 1].delta {
            dirac(i + 1, i + 2, i, TransportMode::Importance)
        } else {
            let prev = (i + 2 < n).then(|| &path[i + 2]);
            PathView::density(scene, prev, &path[i + 1], &path[i], TransportMode::Importance) as f64
        };
    }
    p
}

#[test]
fn rebuilt_strategy_paths_evaluate_to_what_bdpt_weighted() {
    for rel in [
        "scenes/cornell-box/scene.xml",
        "scenes/materials/scene.xml",
        "scenes/caustic/scene.xml",
        "scenes/fig17/scene.xml",
        "scenes/nested-glass/scene.xml",
    ] {
        let scene = scene(rel);
        let bdpt = bdpt(&scene);
        let (mut checked, mut with_dirac) = (0, 0);
        for i in 0..400 {
            let mut ctx = PssContext::new(&scene, &bdpt, Pssmlt::seed_pss(7, i));
            let (_, sub) = ctx.evaluate_with_paths();
            for c in ctx.contributions() {
                let path = c.path(&sub);
                assert_eq!(path.len(), c.s + c.t, "{rel}: strategy ({}, {}) rebuilt wrong length", c.s, c.t);
                let state = PathState::new(&scene, path.clone());
                let Some(state) = state else {
                    panic!(
                        "{rel}: BDPT's strategy ({}, {}) carries {:?} but its path evaluates to nothing",
                        c.s, c.t, c.value
                    )
                };
                if path.iter().any(|v| v.delta) {
                    // With the Dirac convention (deltas removed from f and from the densities alike),
                    // f/p of the sampled strategy must be BDPT's unweighted estimate.
                    let rr = scene.integrator.rr_depth.max(0) as usize;
                    if c.s > rr || c.t > rr || c.s < 2 {
                        continue;
                    }
                    let p = dirac_strategy_density(&scene, &path, c.t);
                    let view = PathView::whole(&path);
                    let pdfs = view.pdfs(&scene);
                    let w = mis_weight(&scene, &view, &pdfs, c.t, MisHeuristic::Power) as f64;
                    let expected = state.luminance() * w / p;
                    let got = luminance(c.value) as f64;
                    assert!(
                        (expected - got).abs() <= 1e-2 * got.max(expected) + 1e-12,
                        "{rel}: Dirac path, strategy ({}, {}): BDPT {got:.6e}, w f / p {expected:.6e}",
                        c.s,
                        c.t
                    );
                    with_dirac += 1;
                    continue;
                }
                // Russian roulette divides BDPT's throughput by continuation probabilities that a
                // density recomputed from positions does not know: compare only before it starts.
                let rr = scene.integrator.rr_depth.max(0) as usize;
                if c.s > rr || c.t > rr {
                    continue;
                }
                let view = PathView::whole(&path);
                let pdfs = view.pdfs(&scene);
                let w = mis_weight(&scene, &view, &pdfs, c.t, MisHeuristic::Power) as f64;
                let p = strategy_density(&scene, &path, c.t);
                if p.is_nan() || p <= 0.0 {
                    continue;
                }
                let expected = state.luminance() * w / p;
                let got = luminance(c.value) as f64;
                // Sampled throughputs (weight = f cos / pdf, in f32 per bounce) and the from-scratch
                // evaluation differ by rounding of order 1e-3 on long glossy paths; a wrong vertex or
                // strategy would be off by factors.
                assert!(
                    (expected - got).abs() <= 1e-2 * got.max(expected) + 1e-12,
                    "{rel}: strategy ({}, {}): BDPT {got:.6e}, w f / p of the rebuilt path {expected:.6e}",
                    c.s,
                    c.t
                );
                checked += 1;
            }
        }
        assert!(checked + with_dirac > 100, "{rel}: only {checked} + {with_dirac} strategies checked");
        if rel.contains("caustic") {
            assert!(with_dirac > 0, "the caustic scene must produce paths through the glass ball");
        }
    }
}

#[test]
fn seed_draws_follow_the_weighted_contributions() {
    let scene = scene("scenes/cornell-box/scene.xml");
    let bdpt = bdpt(&scene);
    let n = 20_000;
    let seeds = PathSeeds::run(&scene, &bdpt, 3, n, &AtomicBool::new(false));
    assert!(seeds.b > 0.0 && seeds.candidates() > n / 4);
    // Draws are ∝ the luminance y of each weighted strategy, so the mean drawn path length must be
    // Σ len·y / Σ y over all strategies of the pass, recomputed here by replaying every seed sample.
    let mut sum_y = 0.0;
    let mut sum_len_y = 0.0;
    for i in 0..n {
        let mut ctx = PssContext::new(&scene, &bdpt, Pssmlt::seed_pss(3, i));
        ctx.evaluate();
        for c in ctx.contributions() {
            let y = luminance(c.value) as f64;
            sum_y += y;
            sum_len_y += (c.s + c.t) as f64 * y;
        }
    }
    assert!((sum_y / n as f64 - seeds.b).abs() <= 1e-9 * seeds.b, "b is the mean per-sample luminance");
    let expected_len = sum_len_y / sum_y;
    let mut rng = Sampler::new(11, 0, 0);
    let draws = 4000;
    let lens: Vec<f64> = (0..draws)
        .map(|_| seeds.draw(&scene, &bdpt, 3, rng.next_f64()).expect("a drawn seed replays").len() as f64)
        .collect();
    let mean = lens.iter().sum::<f64>() / draws as f64;
    let var = lens.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (draws - 1) as f64;
    let se = (var / draws as f64).sqrt();
    assert!(
        (mean - expected_len).abs() <= 5.0 * se,
        "mean drawn path length {mean:.4} ± {se:.4}, expected {expected_len:.4}"
    );
}

/// The seeding pass keeps one running sum per group of samples, and a draw replays its group: the
/// path drawn for u must be the strategy at which the running sum over every strategy of the pass
/// passes u · Σ, exactly as with a sum kept per strategy; a pass run in two parts (a time-limited
/// pass extends itself) must give the same b and the same draws as one pass.
#[test]
fn seed_draws_are_the_strategies_where_the_running_sum_passes_u() {
    let scene = scene("scenes/cornell-box/scene.xml");
    let bdpt = bdpt(&scene);
    let (n, seed, cut) = (3000, 5, 1001);
    let cancel = AtomicBool::new(false);
    let whole = PathSeeds::run(&scene, &bdpt, seed, n, &cancel);
    // A long pass keeps one sum per 16 samples and replays the group on a draw; a short one keeps a
    // sum per sample. Both, and a pass of parts mixing them, must draw the same paths.
    let grouped = PathSeeds::run_grouped(&scene, &bdpt, seed, 0..n, 16, &cancel);
    let mut parts = PathSeeds::run_grouped(&scene, &bdpt, seed, 0..cut, 16, &cancel);
    parts.append(PathSeeds::run_range(&scene, &bdpt, seed, cut..n, &cancel));
    let mut running = Vec::new();
    let (mut sum, mut squares) = (0.0, 0.0);
    for i in 0..n {
        let mut ctx = PssContext::new(&scene, &bdpt, Pssmlt::seed_pss(seed, i));
        let (_, sub) = ctx.evaluate_with_paths();
        let before = sum;
        for c in ctx.contributions() {
            let y = luminance(c.value) as f64;
            if y > 0.0 && y.is_finite() {
                sum += y;
                running.push((sum, c.path(&sub)));
            }
        }
        squares += (sum - before).powi(2);
    }
    // b's standard error from the samples' spread: exact with a sum per sample, estimated from the
    // groups' spread otherwise (188 groups of 16 here, so within a few tens of percent).
    let mean = sum / n as f64;
    let standard_error = ((squares / n as f64 - mean * mean) / n as f64).sqrt();
    let relative = |seeds: &PathSeeds| seeds.b_standard_error() / standard_error - 1.0;
    assert!(relative(&whole).abs() < 1e-6, "one pass: b's error off by {:.3}", relative(&whole));
    assert!(relative(&grouped).abs() < 0.3, "grouped: b's error off by {:.3}", relative(&grouped));
    assert!(relative(&parts).abs() < 0.3, "two parts: b's error off by {:.3}", relative(&parts));
    for (name, seeds) in [("one pass", &whole), ("grouped", &grouped), ("two parts", &parts)] {
        assert_eq!(seeds.samples, n, "{name}");
        assert_eq!(seeds.candidates(), running.len(), "{name}");
        assert!(
            (seeds.b - sum / n as f64).abs() <= 1e-12 * seeds.b,
            "{name}: b {} against {}",
            seeds.b,
            sum / n as f64
        );
        let largest = running.windows(2).map(|w| w[1].0 - w[0].0).fold(running[0].0, f64::max);
        assert!((seeds.largest_share() - largest / sum).abs() <= 1e-9, "{name}: largest share");
        for k in 0..300 {
            let u = (k as f64 + 0.5) / 300.0;
            let expected = &running[running.partition_point(|(c, _)| *c <= u * sum)].1;
            let drawn = seeds.draw(&scene, &bdpt, seed, u).expect("a drawn seed replays");
            let positions = |p: &[Vertex]| p.iter().map(|v| v.p).collect::<Vec<_>>();
            assert_eq!(positions(&drawn.vertices), positions(expected), "{name}: draw at u = {u}");
        }
    }
}

/// b's standard error as the seeding pass reports it (the normalisation's error, in the metadata as
/// `hslt.mlt.b_seed_relative_error`) matches the spread of b over independent passes, grouped or not.
#[test]
fn the_seeding_pass_knows_the_error_of_its_b() {
    let scene = scene("scenes/cornell-box/scene.xml");
    let bdpt = bdpt(&scene);
    let cancel = AtomicBool::new(false);
    for group in [1, 16] {
        let passes: Vec<PathSeeds> = (0..12)
            .map(|seed| PathSeeds::run_grouped(&scene, &bdpt, seed, 0..8192, group, &cancel))
            .collect();
        let bs: Vec<f64> = passes.iter().map(|p| p.b).collect();
        let mean = bs.iter().sum::<f64>() / bs.len() as f64;
        let spread = (bs.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / (bs.len() - 1) as f64).sqrt();
        let reported = passes.iter().map(|p| p.b_standard_error()).sum::<f64>() / passes.len() as f64;
        // 12 passes estimate the spread to about ±20%.
        let ratio = spread / reported;
        assert!(
            (0.5..2.0).contains(&ratio),
            "groups of {group}: spread {spread:.3e}, reported {reported:.3e}"
        );
    }
}

/// A time-limited path-space render runs its seeding pass for its share of the time (`--seed-share`),
/// past the fixed-work default, and an explicit `--seed-paths` is run exactly.
#[test]
fn a_time_limited_seeding_pass_runs_for_its_share_of_the_time() {
    let scene = scene("scenes/cornell-box/scene.xml");
    let run = |settings: MltSettings, options: RenderOptions| {
        let mlt = PathMlt::new("mlt", bdpt(&scene), settings);
        let out = mlt.render(&scene, &options, &AtomicBool::new(false));
        let value = |key: &str| out.metadata.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone());
        let paths: usize = value("hslt.mlt.seed_paths").expect("seed paths recorded").parse().unwrap();
        let seconds: f64 = value("hslt.mlt.seconds_seeding").expect("seeding time recorded").parse().unwrap();
        (paths, seconds)
    };
    let mixture = || MltSettings::for_technique(vec![(MutationKind::Bidirectional, 1.0)]);
    let default_paths = hslt::metropolis::mlt::default_seed_paths(32 * 32, u64::MAX);
    // The fixed minimum alone, run exactly, gives this machine's cost of it (tests share the cores),
    // and the time limit is set from it so the pass has room to grow on a slow or busy machine.
    let fixed = RenderOptions { spp: Some(1), seed: 2, ..Default::default() };
    let (paths, minimum_seconds) = run(MltSettings { seed_paths: Some(default_paths), ..mixture() }, fixed);
    assert_eq!(paths, default_paths);
    let limit = 4.0 * minimum_seconds + 1.0;
    let budget = 0.5 * limit;
    let timed = RenderOptions {
        time_limit: Some(std::time::Duration::from_secs_f64(limit)),
        seed: 2,
        ..Default::default()
    };
    let (paths, seconds) = run(MltSettings { seed_share: 0.5, ..mixture() }, timed);
    assert!(
        paths > default_paths,
        "{paths} seed paths in {seconds} s, no more than the default {default_paths} (which took {minimum_seconds} s)"
    );
    // The pass sizes each batch by its rate so far, so it ends near its budget.
    assert!(
        seconds >= 0.5 * budget && seconds <= budget + minimum_seconds + 1.0,
        "the seeding pass took {seconds} s for a budget of {budget} s (the minimum took {minimum_seconds} s)"
    );
}

/// Light trapped in the jewelry scene's diamond by total internal reflection makes BDPT paths of
/// dozens of vertices whose f in product area measure (one 1/d² and one near-specular BSDF peak per
/// vertex) overflows f32. Every one must still become a chain state, with f carried as colour · scale:
/// before, they evaluated to ∞ and were dropped, so seeds on them were redrawn elsewhere and no
/// mutation could reach them; the path-space images lost a fifth of the diamond's light.
///
/// A few paths BDPT weights do evaluate to zero: a Beckmann peak of α = 0.02 far off its lobe
/// underflows f32 in the evaluated BSDF, while BDPT's sampled weight never forms it. Their share of
/// the light is bounded here instead.
#[test]
fn paths_whose_contribution_overflows_f32_are_still_states() {
    let scene = scene("scenes/jewelry/scene.xml");
    let bdpt = bdpt(&scene);
    let (mut states, mut scaled, mut longest) = (0usize, 0usize, 0usize);
    let (mut total, mut lost) = (0.0f64, 0.0f64);
    for i in 0..20_000 {
        let mut ctx = PssContext::new(&scene, &bdpt, Pssmlt::seed_pss(5, i));
        let (_, sub) = ctx.evaluate_with_paths();
        for c in ctx.contributions() {
            let y = luminance(c.value) as f64;
            if !(y > 0.0 && y.is_finite()) {
                continue;
            }
            total += y;
            let path = c.path(&sub);
            let n = path.len();
            let Some(state) = PathState::new(&scene, path) else {
                lost += y;
                continue;
            };
            let target = TargetFunction::Luminance.of(&state);
            assert!(target > 0.0 && target.is_finite(), "{n} vertices: target {target:e}");
            assert!((target - state.luminance()).abs() <= 1e-9 * target);
            if state.scale != 1.0 {
                scaled += 1;
                // The colour is normalised to its largest channel, so the scale holds the magnitude.
                assert!((state.contribution.max_element() - 1.0).abs() < 1e-6);
                assert!(state.scale > 1e30 || state.scale < 1e-30, "scale {:e} needlessly", state.scale);
            }
            states += 1;
            longest = longest.max(n);
        }
    }
    println!(
        "{states} states, {scaled} beyond f32's comfortable range, longest {longest} vertices; \
         {:.2e} of the weighted light on paths that evaluate to nothing",
        lost / total
    );
    assert!(scaled > 0, "no path of the diamond left f32's range ({states} states, longest {longest})");
    assert!(lost <= 1e-5 * total, "{:.2e} of BDPT's light has no chain state", lost / total);
}

/// Chains start on seed draws, and a draw whose path does not evaluate is redrawn elsewhere, moving its
/// share of b; the render counts such redraws (`hslt.mlt.seed_redraws`). On the Cornell box every
/// BDPT strategy path evaluates, so there are none. (On jewelry at 32×32, seeds 1–3 give 0, 0 and 1:
/// a 27-vertex path with two vertices 0.14 mm apart across a gem facet edge, which BDPT reached by a
/// ray from an offset origin and weighted 0.92 but whose BSDF at the vertices' own positions is ~0.)
#[test]
fn no_seed_draw_is_redrawn_on_the_cornell_box() {
    let scene = scene("scenes/cornell-box/scene.xml");
    let mlt = PathMlt::new(
        "mlt",
        bdpt(&scene),
        MltSettings::for_technique(vec![(MutationKind::Bidirectional, 1.0)]),
    );
    for seed in 1..=3 {
        let options = RenderOptions { spp: Some(1), seed, ..Default::default() };
        let out = mlt.render(&scene, &options, &AtomicBool::new(false));
        let value = |key: &str| out.metadata.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone());
        // One mutation per pixel: no more chains than mutations.
        let chains = DEFAULT_PATH_CHAINS.min(32 * 32);
        assert_eq!(value("hslt.mlt.chains"), Some(chains.to_string()), "seed {seed}");
        assert_eq!(
            value("hslt.mlt.seed_redraws").as_deref(),
            Some("0"),
            "seed {seed}: seed draws were redrawn"
        );
    }
}
