//! The Metropolis integrators' separate direct-illumination pass (`metropolis::direct`, Mitsuba's
//! `directSamples`): the chains keep paths of three or more segments, BDPT renders the rest, and the
//! sum is the whole image (the convergence tests in tests/metropolis_convergence.rs check that sum
//! against BDPT on every bundled scene).

use hslt::cli::load_scene;
use hslt::metropolis::direct::DirectPass;
use hslt::registry::{make_with, IntegratorKind, IntegratorSettings};
use hslt::render::{DepthLimits, RenderOptions, RenderOutput};
use hslt::scene::Scene;
use std::path::Path;
use std::sync::atomic::AtomicBool;

mod common;

use common::mlt::image_mean;

fn cornell(defines: &[(&str, &str)]) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let mut all = vec![("resx", "32"), ("resy", "32")];
    all.extend_from_slice(defines);
    load_scene(&path, &all).expect("cornell box")
}

fn render(scene: &Scene, kind: IntegratorKind, spp: u32, seed: u64, direct: DirectPass) -> RenderOutput {
    render_from_depth(scene, kind, spp, seed, direct, 1)
}

fn render_from_depth(
    scene: &Scene,
    kind: IntegratorKind,
    spp: u32,
    seed: u64,
    direct: DirectPass,
    min_depth: i32,
) -> RenderOutput {
    let limits = DepthLimits::of_scene(scene);
    let mut settings = IntegratorSettings::new(limits, scene.integrator.hide_emitters);
    settings.pssmlt.seed_paths = Some(16_384);
    settings.pssmlt.direct = direct;
    settings.min_depth = min_depth;
    let options = RenderOptions { spp: Some(spp), seed, ..Default::default() };
    make_with(kind, &settings).render(scene, &options, &AtomicBool::new(false))
}

fn meta<'a>(out: &'a RenderOutput, key: &str) -> Option<&'a str> {
    out.metadata.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

fn metropolis_kinds() -> Vec<IntegratorKind> {
    IntegratorKind::available_kinds()
        .into_iter()
        .filter(|k| !matches!(k, IntegratorKind::Path | IntegratorKind::Bdpt))
        .collect()
}

#[test]
fn without_indirect_light_the_image_is_the_direct_pass() {
    // max_depth 2 leaves the chains nothing: every Metropolis integrator must say so and return the
    // direct pass (the path tracer, and BDPT for emitters seen directly), checked against full BDPT. 32×32 at 256
    // spp: the image means of two such renders differ by a few tenths of a percent, so 2% is about
    // ten standard errors.
    let scene = cornell(&[("max_depth", "2")]);
    let out = render(&scene, IntegratorKind::Bdpt, 256, 7, DirectPass::Off);
    let reference = image_mean(&out.film.to_image());
    for kind in metropolis_kinds() {
        let out = render(&scene, kind, 4, 1, DirectPass::Samples(256));
        let status = meta(&out, "hslt.mlt.status").unwrap_or_else(|| panic!("{}: no status", kind.name()));
        assert!(status.contains("three or more segments"), "{}: {status}", kind.name());
        assert_eq!(meta(&out, "hslt.mlt.direct_samples"), Some("256"), "{}", kind.name());
        let img = out.film.to_image();
        assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{}", kind.name());
        let mean = image_mean(&img);
        assert!(
            (mean / reference - 1.0).abs() < 0.02,
            "{}: direct pass mean {mean:.5} against BDPT {reference:.5}",
            kind.name()
        );
    }
}

#[test]
fn chains_reject_what_the_direct_pass_renders_and_only_then() {
    let scene = cornell(&[]);
    for kind in [IntegratorKind::Mlt, IntegratorKind::Hslt] {
        let split = render(&scene, kind, 8, 3, DirectPass::Samples(4));
        assert_eq!(meta(&split, "hslt.mlt.direct_samples"), Some("4"));
        let outside: u64 = split
            .metadata
            .iter()
            .filter(|(k, _)| k.ends_with(".failed.outside_support"))
            .map(|(_, v)| v.parse::<u64>().unwrap())
            .sum();
        // The bidirectional mutation and the large step draw lengths from BDPT's range, which the
        // pass raises to three segments, so no proposal needs the support check (which stays as a
        // guard; `metropolis_pssmlt.rs` tests it): a short proposal would be a length outside it.
        assert_eq!(outside, 0, "{}: proposals shorter than the chains' support", kind.name());
        let whole = render(&scene, kind, 8, 3, DirectPass::Off);
        assert_eq!(meta(&whole, "hslt.mlt.direct_samples"), None);
        assert!(!whole.metadata.iter().any(|(k, _)| k.ends_with(".failed.outside_support")));
        // b covers indirect light only when the pass is on: the Cornell box's direct light is about
        // three quarters of the image.
        let b = |o: &RenderOutput| meta(o, "hslt.mlt.normalization").unwrap().parse::<f64>().unwrap();
        let ratio = b(&split) / b(&whole);
        assert!((0.1..0.5).contains(&ratio), "{}: b with the pass / without {ratio:.3}", kind.name());
    }
}

#[test]
fn depth_ranges_add_up_and_the_unidirectional_and_bidirectional_splits_agree() {
    // What --min-depth 3 leaves (indirect light) and what --max-depth 2 keeps (direct light) must add
    // up to the whole image, and the path tracer and BDPT must leave out the same paths.
    let scene = cornell(&[]);
    let runs = 4;
    let mean_of = |kind: IntegratorKind, scene: &Scene, min_depth: i32, spp: u32| {
        let means: Vec<f64> = (1..=runs)
            .map(|seed| {
                let out = render_from_depth(scene, kind, spp, seed, DirectPass::Off, min_depth);
                image_mean(&out.film.to_image())
            })
            .collect();
        common::mlt::mean_se(&means)
    };
    let whole = mean_of(IntegratorKind::Path, &scene, 1, 64);
    let direct = mean_of(IntegratorKind::Path, &cornell(&[("max_depth", "2")]), 1, 64);
    let indirect_pt = mean_of(IntegratorKind::Path, &scene, 3, 64);
    let indirect_bdpt = mean_of(IntegratorKind::Bdpt, &scene, 3, 16);
    eprintln!("whole {whole:?} direct {direct:?} indirect pt {indirect_pt:?} bdpt {indirect_bdpt:?}");
    let sum_se = (whole.1.powi(2) + direct.1.powi(2) + indirect_pt.1.powi(2)).sqrt();
    assert!(
        (direct.0 + indirect_pt.0 - whole.0).abs() < 5.0 * sum_se,
        "direct {direct:?} + indirect {indirect_pt:?} against the whole image {whole:?}"
    );
    let se = (indirect_pt.1.powi(2) + indirect_bdpt.1.powi(2)).sqrt();
    assert!(
        (indirect_pt.0 - indirect_bdpt.0).abs() < 5.0 * se,
        "indirect light: path tracer {indirect_pt:?}, BDPT {indirect_bdpt:?}"
    );
    // The Cornell box's indirect light is about a quarter of the image: the split did leave some out.
    let share = indirect_pt.0 / whole.0;
    assert!((0.1..0.5).contains(&share), "indirect share {share:.3}");
}

#[test]
fn from_depth_three_the_chains_render_alone_and_match_bdpt() {
    // The direct pass renders exactly what --min-depth 3 leaves out, so it must not run (the chains
    // get the whole budget) and the chains' image alone must be BDPT's indirect light.
    let scene = cornell(&[]);
    let means: Vec<f64> = (1..=4)
        .map(|seed| {
            image_mean(
                &render_from_depth(&scene, IntegratorKind::Bdpt, 16, seed, DirectPass::Off, 3)
                    .film
                    .to_image(),
            )
        })
        .collect();
    let (reference, _) = common::mlt::mean_se(&means);
    for kind in metropolis_kinds() {
        let out = render_from_depth(&scene, kind, 16, 1, DirectPass::Auto, 3);
        assert_eq!(meta(&out, "hslt.mlt.direct_samples"), None, "{}: the direct pass ran", kind.name());
        let img = out.film.to_image();
        assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{}", kind.name());
        let mean = image_mean(&img);
        eprintln!("{} {mean:.5} against {reference:.5}", kind.name());
        assert!(
            (mean / reference - 1.0).abs() < 0.05,
            "{}: indirect light {mean:.5} against BDPT {reference:.5}",
            kind.name()
        );
    }
}
