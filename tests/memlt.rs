//! Manifold exploration's perturbation (MEMLT): the change of measure at Dirac vertices, detailed
//! balance of the proposal as a statistical identity over stationary pairs, and chains that run only
//! this perturbation reproducing BDPT.

use glam::{DMat2, DVec2};
use hslt::cli::load_scene;
use hslt::image::ImageBuf;
use hslt::manifold::{
    direction_per_half_vector, half_vector_constraint, path_constraints, path_etas, path_geometry, walk,
    LocalGeometry, WalkSettings,
};
use hslt::metropolis::{
    ManifoldPerturbation, MltSettings, Mutation, MutationKind, MutationStats, PathContext, PathMlt,
    PathSeeds, TargetFunction,
};
use hslt::render::{Integrator, RenderOptions};
use hslt::sampling::Sampler;
use hslt::scene::Scene;
use std::path::Path;
use std::sync::atomic::AtomicBool;

mod common;

use common::mlt::{bdpt, mean_se};

fn scene(rel: &str, defines: &[(&str, &str)]) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    load_scene(&path, defines).unwrap_or_else(|e| panic!("{rel}: {e:#}"))
}

/// At a Dirac vertex the half-vector constraint's block towards the next vertex, C = ∂h/∂x_{i+1}, and
/// the solid-angle-per-half-vector factor must multiply to the plain solid-angle-to-area factor
/// |cos_{i+1}| / d²: moving x_{i+1} turns ω_o (that factor) and h only through ω_o. This ties the
/// closed-form factor to the constraint code that the walk and the acceptance ratio share.
#[test]
fn dirac_factor_matches_the_constraint_block() {
    let scene = scene("scenes/caustic/scene.xml", &[("resx", "32"), ("resy", "32")]);
    let bdpt = bdpt(&scene);
    let seeds = PathSeeds::run(&scene, &bdpt, 5, 20_000, &AtomicBool::new(false));
    let mut rng = Sampler::new(3, 0, 0);
    let mut checked = 0;
    for _ in 0..3000 {
        let Some(x) = seeds.draw(&scene, &bdpt, 5, rng.next_f64()) else { continue };
        let v = &x.vertices;
        let g = path_geometry(v);
        let eta = path_etas(&scene, v);
        for i in 1..v.len() - 1 {
            if !v[i].delta {
                continue;
            }
            let vc = half_vector_constraint(&g[i - 1], &g[i], &g[i + 1], eta[i]).unwrap();
            let wi = (g[i - 1].p - g[i].p).normalize();
            let wo = (g[i + 1].p - g[i].p).normalize();
            let j = direction_per_half_vector(&g[i], wi, wo, eta[i]).unwrap();
            let conv = v[i].convert_density(1.0, &v[i + 1], &scene) as f64;
            let got = vc.c.determinant().abs() * j;
            // f32 vertex positions: relative agreement to ~1e-4 on well-conditioned vertices.
            assert!(
                (got - conv).abs() <= 2e-3 * conv,
                "vertex {i}: |det C| J_w = {got:.6e}, conv {conv:.6e}"
            );
            checked += 1;
        }
    }
    assert!(checked > 500, "only {checked} Dirac vertices checked");
}

/// The chain weight the acceptance ratio uses for a walked specular chain, 1 / (|det J| Π |dω_o/dh⊥|),
/// must equal the generalised geometry term over the plain ones, |det ∂s_1/∂x_c| / Π conv(edges after
/// s_1): how far the first chain vertex follows the fixed end, measured here by re-walking the chain
/// with the end displaced (central differences), independently of the determinant and the closed-form
/// factors.
#[test]
fn chain_weight_matches_finite_differences_of_the_walk() {
    let scene = scene("scenes/caustic/scene.xml", &[("resx", "32"), ("resy", "32")]);
    let bdpt = bdpt(&scene);
    let seeds = PathSeeds::run(&scene, &bdpt, 9, 40_000, &AtomicBool::new(false));
    let mut rng = Sampler::new(4, 0, 0);
    let settings = WalkSettings { tolerance: 2e-6, relative_tolerance: 1.0, ..Default::default() };
    let mut errors = Vec::new();
    for _ in 0..4000 {
        let Some(x) = seeds.draw(&scene, &bdpt, 9, rng.next_f64()) else { continue };
        let v = &x.vertices;
        // E D S S L: the chain (x_1 | s_1 s_2 | light).
        if v.len() != 5 || v[1].delta || !v[2].delta || !v[3].delta {
            continue;
        }
        let sub: Vec<_> = v[1..].to_vec();
        let eta = path_etas(&scene, &sub);
        let zero = [DVec2::ZERO; 2];
        // Put the chain exactly on the manifold first (seed paths carry ~1e-4 of ray-offset error).
        let Ok(base) = walk(&scene, &sub, &eta, &zero, &settings) else { continue };
        let g = path_geometry(&base.path);
        let Ok(constraints) = path_constraints(&g, &eta) else { continue };
        let Ok(lu) = constraints.jacobian.factor() else { continue };
        let mut analytic = -lu.log_det().ln_abs;
        for i in 1..3 {
            let (wi, wo) = ((g[i - 1].p - g[i].p).normalize(), (g[i + 1].p - g[i].p).normalize());
            analytic -= direction_per_half_vector(&g[i], wi, wo, eta[i]).unwrap().ln();
        }
        // ∂s_1/∂x_c by moving the light point along its tangents and re-walking.
        let light = LocalGeometry::from_vertex(&base.path[3]);
        let s1 = g[1];
        let h = 3e-4;
        let moved = |d: DVec2| -> Option<DVec2> {
            let mut start = base.path.clone();
            start[3].p = (light.p + light.displacement(d)).as_vec3();
            let r = walk(&scene, &start, &eta, &zero, &settings).ok()?;
            let dp = r.path[1].p.as_dvec3() - s1.p;
            Some(DVec2::new(dp.dot(s1.tu), dp.dot(s1.tv)))
        };
        let (Some(up), Some(um), Some(vp), Some(vm)) =
            (moved(DVec2::X * h), moved(-DVec2::X * h), moved(DVec2::Y * h), moved(-DVec2::Y * h))
        else {
            continue;
        };
        let d = DMat2::from_cols((up - um) / (2.0 * h), (vp - vm) / (2.0 * h));
        let conv = |a: usize, b: usize| base.path[a].convert_density(1.0, &base.path[b], &scene) as f64;
        let numeric = d.determinant().abs().ln() - conv(1, 2).ln() - conv(2, 3).ln();
        errors.push((analytic - numeric).abs());
    }
    // The analytic weight is exact inside one triangle of the tessellated ball; a difference quotient
    // whose ±3e-4 displacements carry a vertex across an edge (where interpolated normals bend) is
    // not, so judge the bulk: a missing or wrong factor would be off by O(1) on every chain.
    errors.sort_by(f64::total_cmp);
    let n = errors.len();
    assert!(n >= 100, "only {n} chains checked");
    let (median, p70) = (errors[n / 2], errors[n * 7 / 10]);
    println!("{n} chains: |ln analytic − ln numeric| median {median:.2e}, 70th percentile {p70:.2e}");
    assert!(median < 1e-3 && p70 < 3e-3, "median {median:.2e}, 70th percentile {p70:.2e}");
}

struct PairStats {
    proposals: usize,
    valid: usize,
    /// R · 1{valid} per proposal.
    r_valid: Vec<f64>,
    /// R · 1{R < 1} per proposal.
    r_below: Vec<f64>,
    /// 1{R > 1} per proposal.
    above: Vec<f64>,
    failures: MutationStats,
}

/// x drawn ∝ the target from a large seeding pass (a stationary sample), y ~ T(x, ·), and
/// R = target(y) T(y→x) / (target(x) T(x→y)), the unclipped acceptance ratio.
fn pairs(scene: &Scene, mutation: &mut ManifoldPerturbation, draws: usize, pool: usize) -> PairStats {
    let bdpt = bdpt(scene);
    let seeds = PathSeeds::run(scene, &bdpt, 17, pool, &AtomicBool::new(false));
    let target = TargetFunction::Luminance;
    let mut ctx = PathContext::new(scene, &bdpt);
    let mut rng = Sampler::new(29, 1, 0);
    let mut out = PairStats {
        proposals: 0,
        valid: 0,
        r_valid: Vec::new(),
        r_below: Vec::new(),
        above: Vec::new(),
        failures: MutationStats::default(),
    };
    while out.proposals < draws {
        let Some(x) = seeds.draw(scene, &bdpt, 17, rng.next_f64()) else { continue };
        let mut stats = MutationStats::default();
        let result = mutation.propose(&x, &mut ctx, &mut rng, &mut stats);
        if matches!(result, Err(hslt::metropolis::Failure::NotApplicable)) {
            continue;
        }
        out.proposals += 1;
        let r = match result {
            Ok(p) => {
                assert!(p.t_ratio.is_finite() && p.t_ratio >= 0.0, "t_ratio {}", p.t_ratio);
                let r = target.of(&p.state) * p.t_ratio / target.of(&x);
                assert!(r.is_finite(), "R = {r}");
                out.valid += 1;
                Some(r)
            }
            Err(hslt::metropolis::Failure::Failed(reason)) => {
                *out.failures.failed.entry(reason).or_insert(0) += 1;
                None
            }
            Err(_) => unreachable!(),
        };
        out.r_valid.push(r.unwrap_or(0.0));
        out.r_below.push(r.filter(|&r| r < 1.0).unwrap_or(0.0));
        out.above.push(r.map_or(0.0, |r| if r > 1.0 { 1.0 } else { 0.0 }));
    }
    out
}

/// With x ~ π and y ~ T(x, ·), exchanging the roles of x and y in ∫ π(x) T(x, y) g(x, y) gives
/// E[R g(x, y)] = E[g(y, x)]. With g = 1{valid} (validity is symmetric: the walk is deterministic
/// and the reversibility check is the reverse proposal) E[R · 1{valid}] = P(valid); with g = 1{R < 1}
/// (R(y, x) = 1/R(x, y)) E[R · 1{R < 1}] = P(R > 1). A wrong density or Jacobian in the ratio shifts R
/// by a factor and breaks both. The seed pool is a finite stand-in for π, so allow 4 standard errors
/// plus 2% for its resampling error.
fn check_balance(name: &str, p: &PairStats) {
    let n = p.proposals as f64;
    let valid = p.valid as f64 / n;
    let (r_valid, se_valid) = mean_se(&p.r_valid);
    let (r_below, se_below) = mean_se(&p.r_below);
    let (above, se_above) = mean_se(&p.above);
    println!(
        "{name}: {} proposals, valid {valid:.3}; E[R·1valid] {r_valid:.4} ± {se_valid:.4}; \
         E[R·1(R<1)] {r_below:.4} ± {se_below:.4} vs P(R>1) {above:.4} ± {se_above:.4}; failures {:?}",
        p.proposals, p.failures.failed
    );
    assert!(p.valid > p.proposals / 10, "{name}: only {} of {} proposals valid", p.valid, p.proposals);
    let se = (se_valid * se_valid + valid * (1.0 - valid) / n).sqrt();
    assert!((r_valid - valid).abs() <= 4.0 * se + 0.02 * valid, "{name}: E[R·1valid] {r_valid} vs {valid}");
    let se = (se_below * se_below + se_above * se_above).sqrt();
    assert!((r_below - above).abs() <= 4.0 * se + 0.02 * above, "{name}: E[R·1(R<1)] {r_below} vs {above}");
}

#[test]
fn detailed_balance_through_glass_chains() {
    // E D S S L (the caustic under the ball: the walk re-aims both refractions at the light) and
    // E S S D L (the floor seen through the ball: the traced chain keeps h = 0).
    let scene = scene("scenes/caustic/scene.xml", &[("resx", "32"), ("resy", "32")]);
    let mut m = ManifoldPerturbation::new(50.0, 0.1);
    check_balance("caustic λ=50", &pairs(&scene, &mut m, 6000, 100_000));
    let mut m = ManifoldPerturbation::new(5.0, 0.1);
    check_balance("caustic λ=5", &pairs(&scene, &mut m, 6000, 100_000));
}

#[test]
fn detailed_balance_with_glossy_vertices_held() {
    // Rings (α = 0.05) and gems (α = 0.02) below the threshold are held at their half vectors.
    let scene = scene("scenes/jewelry/scene.xml", &[("resx", "48"), ("resy", "36"), ("max_depth", "5")]);
    let mut m = ManifoldPerturbation::new(50.0, 0.1);
    check_balance("jewelry λ=50", &pairs(&scene, &mut m, 4000, 100_000));
}

fn render_mlt(
    scene: &Scene,
    mutations: Vec<(MutationKind, f64)>,
    lambda: f64,
    chains: usize,
    spp: u32,
    seed: u64,
) -> ImageBuf {
    let mut settings = MltSettings::for_technique(mutations);
    settings.seed_paths = Some(60_000);
    settings.chains = chains;
    settings.mutation.lambda = lambda;
    let mlt = PathMlt::new("memlt", bdpt(scene), settings);
    let options = RenderOptions { spp: Some(spp), seed, ..Default::default() };
    let out = mlt.render(scene, &options, &AtomicBool::new(false));
    assert_eq!(out.stats.invalid_samples, 0);
    out.film.to_image()
}

fn quadrant_means(img: &ImageBuf) -> Vec<f64> {
    let (hw, hh) = (img.width / 2, img.height / 2);
    let mut out = vec![0.0; 4];
    for y in 0..img.height {
        for x in 0..img.width {
            let q = (y / hh).min(1) * 2 + (x / hw).min(1);
            let p = img.pixel(x, y);
            out[q] += (p[0] + p[1] + p[2]) as f64 / 3.0 / (hw * hh) as f64;
        }
    }
    out
}

/// Chains started in the stationary distribution stay in it under any mutation that satisfies
/// detailed balance, even one that cannot reach the whole space, so chains that only run the manifold
/// perturbation must reproduce BDPT's image in expectation. MLT noise is correlated, so the error bar
/// is the spread between independent runs, not pixel spread. Few long chains with large steps (λ = 5:
/// σ ≈ 2.5 px) wander far from their start, so a wrong density ratio has time to bias the image.
#[test]
fn manifold_only_chains_reproduce_bdpt() {
    let scene = scene("scenes/caustic/scene.xml", &[("resx", "32"), ("resy", "32")]);
    let runs: Vec<Vec<f64>> = (1..=6)
        .map(|seed| {
            quadrant_means(&render_mlt(&scene, vec![(MutationKind::Manifold, 1.0)], 5.0, 16, 256, seed))
        })
        .collect();
    let (reference, _) = hslt::cli::render_scene(&scene, hslt::registry::IntegratorKind::Bdpt, 1024, 77);
    let reference = quadrant_means(&reference);
    for q in 0..4 {
        let values: Vec<f64> = runs.iter().map(|r| r[q]).collect();
        let (mean, se) = mean_se(&values);
        // 6 runs: the t statistic has 5 degrees of freedom (|t| > 5 has probability 0.4%); the BDPT
        // reference at 1024 spp adds ~1% noise of its own.
        let tol = 5.0 * se + 0.02 * reference[q];
        println!("quadrant {q}: manifold-only {mean:.5} ± {se:.5}, BDPT {:.5}", reference[q]);
        assert!((mean - reference[q]).abs() <= tol, "quadrant {q}: {mean} vs {}", reference[q]);
    }
}
