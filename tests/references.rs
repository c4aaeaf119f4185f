//! The path tracer and BDPT against images made by other renderers: Mitsuba 3 references of our bundled
//! scenes (made by scripts/make-mitsuba-references.py, same XML) and the Tungsten references that
//! ship with the shared public scenes. See tests/common for the statistical test.
//!
//! Threshold: the χ² per degree of freedom of block differences must stay below 1.5. With a few
//! hundred blocks an unbiased renderer gives 1 ± 0.1 (σ = sqrt(2/dof)), so noise stays far from 1.5,
//! while a bias of a few standard errors in a fraction of the blocks exceeds it.

mod common;

use hslt::cli::{load_scene, render_scene, render_scene_film};
use hslt::image::read_image;
use hslt::registry::IntegratorKind;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shared_scene(name: &str) -> PathBuf {
    common::shared_scenes().join(name)
}

/// How one reference comparison is set up.
struct Check<'a> {
    defines: &'a [(&'a str, &'a str)],
    spp: u32,
    block: (usize, usize),
    /// Image rows compared (all when `None`).
    rows: Option<std::ops::Range<usize>>,
    ref_noise_ratio: f64,
    model_tolerance: f64,
}

fn check_against_reference(scene: &Path, reference: &Path, c: Check) {
    let s = load_scene(scene, c.defines).unwrap_or_else(|e| panic!("{}: {e:#}", scene.display()));
    let reference = read_image(reference, false).unwrap();
    let (film, stats) = render_scene_film(&s, IntegratorKind::Path, c.spp, 1);
    assert_eq!(stats.invalid_samples, 0);
    let rows = c.rows.unwrap_or(0..film.height);
    let cmp = common::compare(
        &film.to_image(),
        &film.variance_image(),
        &reference,
        c.block,
        rows,
        c.ref_noise_ratio,
        c.model_tolerance,
    );
    eprintln!(
        "{}: flux ratio {:.4}, block relMSE {:.2e}, chi2/dof {:.2} over {} blocks",
        scene.display(),
        cmp.flux_ratio,
        cmp.block_rel_mse,
        cmp.chi2_per_dof,
        cmp.blocks
    );
    assert!(
        cmp.chi2_per_dof < 1.5,
        "{}: chi2/dof {:.2} (flux ratio {:.4})",
        scene.display(),
        cmp.chi2_per_dof,
        cmp.flux_ratio
    );
    assert!((cmp.flux_ratio - 1.0).abs() < 0.02, "{}: flux ratio {:.4}", scene.display(), cmp.flux_ratio);
}

#[test]
fn cornell_box_matches_mitsuba() {
    // Reference: 4096 spp, so its variance is 256/4096 of ours; both renderers share the model exactly.
    check_against_reference(
        &root().join("scenes/cornell-box/scene.xml"),
        &root().join("tests/references/mitsuba/cornell-box.exr"),
        Check {
            defines: &[("resx", "64"), ("resy", "64")],
            spp: 256,
            block: (4, 4),
            rows: None,
            ref_noise_ratio: 256.0 / 4096.0,
            model_tolerance: 0.003,
        },
    );
}

#[test]
fn materials_scene_matches_mitsuba() {
    // Rough gold and rough glass spheres. Our spheres are tessellated (area within 1e-3) where Mitsuba's
    // are analytic, hence a 1% model allowance.
    check_against_reference(
        &root().join("scenes/materials/scene.xml"),
        &root().join("tests/references/mitsuba/materials.exr"),
        Check {
            defines: &[("resx", "64"), ("resy", "48")],
            spp: 512,
            block: (4, 4),
            rows: None,
            ref_noise_ratio: 512.0 / 8192.0,
            model_tolerance: 0.01,
        },
    );
}

#[test]
fn shared_cornell_box_matches_tungsten_at_its_resolution() {
    let dir = shared_scene("cornell-box");
    // 1024² at 8 spp, compared in 32×32 blocks (8192 samples each). Tungsten's own noise is taken as
    // that of 32 spp; 1% allows for model differences between the renderers (Mitsuba 3 and Tungsten
    // agree to a flux ratio of 1.0005 on this scene).
    check_against_reference(
        &dir.join("scene.xml"),
        &dir.join("TungstenRender.exr"),
        Check {
            defines: &[],
            spp: 8,
            block: (32, 32),
            rows: None,
            ref_noise_ratio: 0.25,
            model_tolerance: 0.01,
        },
    );
}

#[test]
fn shared_veach_mis_matches_tungsten_at_its_resolution() {
    let dir = shared_scene("veach-mis");
    // Tungsten rendered this scene with direct lighting only: in Mitsuba's convention that is
    // max_depth = 2, while the XML port says 3. Mitsuba 3.9.1 at max_depth 2 matches the Tungsten image
    // to 1% in every block, and at 3 it is up to 30% brighter on the diffuse wall and floor, exactly as
    // we are; so the comparison uses max_depth = 2.
    check_against_reference(
        &dir.join("scene.xml"),
        &dir.join("TungstenRender.exr"),
        Check {
            defines: &[("max_depth", "2")],
            spp: 16,
            block: (40, 40),
            rows: None,
            ref_noise_ratio: 0.25,
            model_tolerance: 0.01,
        },
    );
}

#[test]
fn shared_veach_bidir_matches_tungsten_flux() {
    // As with veach-mis, the XML port says max_depth 7 where Tungsten's render corresponds to 6 in
    // Mitsuba's convention: at 7 Mitsuba 3.9.1 is 1.1% brighter than the Tungsten image and so were we
    // (BDPT 1.4%, the "bias" docs/benchmarks.md once recorded); at 6 Mitsuba gives 0.9998, and BDPT
    // 1.0001, PT 1.0001. The Tungsten image is 1024² with a tent filter; the flux (image mean) does not
    // depend on the resolution, so this renders 64² and compares means to ±0.5% (issue 28), where the
    // seed-to-seed spread is 0.1% (BDPT, 256 spp) and 0.2% (PT, 2048 spp).
    let dir = shared_scene("veach-bidir");
    let reference = read_image(&dir.join("TungstenRender.exr"), false).unwrap();
    let mean = |img: &hslt::image::ImageBuf| {
        let c = img.channels;
        let sum: f64 = img.data.chunks(c).map(|p| p[..3].iter().map(|&v| v as f64).sum::<f64>()).sum();
        sum / (3 * img.width * img.height) as f64
    };
    let s =
        load_scene(&dir.join("scene.xml"), &[("resx", "64"), ("resy", "64"), ("max_depth", "6")]).unwrap();
    for (kind, spp) in [(IntegratorKind::Bdpt, 256), (IntegratorKind::Path, 2048)] {
        let (img, stats) = render_scene(&s, kind, spp, 3);
        assert_eq!(stats.invalid_samples, 0);
        let ratio = mean(&img) / mean(&reference);
        eprintln!("veach-bidir {kind:?}: flux ratio to Tungsten {ratio:.4}");
        assert!((ratio - 1.0).abs() < 0.005, "veach-bidir {kind:?}: flux ratio to Tungsten {ratio:.4}");
    }
}

#[test]
fn all_shared_scenes_load_and_render() {
    // veach-ajar's textures are JPEG files, which only the OpenImageIO build reads.
    let with_jpeg = hslt::image::oiio_version().is_some();
    for name in ["veach-ajar", "veach-bidir", "veach-mis", "cornell-box"] {
        if name == "veach-ajar" && !with_jpeg {
            let err = load_scene(&shared_scene(name).join("scene.xml"), &[]).unwrap_err();
            assert!(format!("{err:#}").contains("oiio"), "{err:#}");
            continue;
        }
        let dir = shared_scene(name);
        let s = load_scene(&dir.join("scene.xml"), &[("resx", "64"), ("resy", "36")])
            .unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let (img, stats) = render_scene(&s, IntegratorKind::Path, 2, 1);
        assert_eq!(stats.invalid_samples, 0, "{name}: NaN/Inf samples");
        let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64;
        assert!(mean > 0.0 && mean.is_finite(), "{name}: mean {mean}");
    }
}

/// BDPT against a reference image, with variances from the spread of `RUNS` independent renders.
const RUNS: u64 = 16;

/// E[t²] for Student's t with RUNS − 1 degrees of freedom (the χ² mean with estimated variances), plus
/// the same 0.5 margin the film-variance tests allow above their mean of 1.
fn runs_threshold() -> f64 {
    let dof = (RUNS - 1) as f64;
    dof / (dof - 2.0) + 0.5
}

fn check_bdpt_against(
    scene: &Path,
    defines: &[(&str, &str)],
    reference: &hslt::image::ImageBuf,
    spp: u32,
    block: (usize, usize),
    ref_noise_ratio: f64,
    model_tolerance: f64,
) {
    let s = load_scene(scene, defines).unwrap_or_else(|e| panic!("{}: {e:#}", scene.display()));
    let (mean, var) = common::render_runs(&s, IntegratorKind::Bdpt, spp, RUNS, block);
    let cmp =
        common::compare(&mean, &var, reference, block, 0..mean.height, ref_noise_ratio, model_tolerance);
    eprintln!(
        "bdpt {}: flux ratio {:.4}, block relMSE {:.2e}, chi2/dof {:.2} over {} blocks (threshold {:.2})",
        scene.display(),
        cmp.flux_ratio,
        cmp.block_rel_mse,
        cmp.chi2_per_dof,
        cmp.blocks,
        runs_threshold()
    );
    assert!(
        cmp.chi2_per_dof < runs_threshold(),
        "bdpt {}: chi2/dof {:.2} (flux ratio {:.4})",
        scene.display(),
        cmp.chi2_per_dof,
        cmp.flux_ratio
    );
    assert!(
        (cmp.flux_ratio - 1.0).abs() < 0.02,
        "bdpt {}: flux ratio {:.4}",
        scene.display(),
        cmp.flux_ratio
    );
}

#[test]
fn bdpt_cornell_box_matches_mitsuba() {
    // 16 runs of 16 spp against Mitsuba's 4096-spp path tracer; BDPT's noise per sample is at most the
    // path tracer's here, so the reference's variance is at most 256/4096 of ours.
    let reference = read_image(&root().join("tests/references/mitsuba/cornell-box.exr"), false).unwrap();
    check_bdpt_against(
        &root().join("scenes/cornell-box/scene.xml"),
        &[("resx", "64"), ("resy", "64")],
        &reference,
        16,
        (4, 4),
        256.0 / 4096.0,
        0.003,
    );
}

#[test]
fn bdpt_materials_scene_matches_mitsuba() {
    let reference = read_image(&root().join("tests/references/mitsuba/materials.exr"), false).unwrap();
    check_bdpt_against(
        &root().join("scenes/materials/scene.xml"),
        &[("resx", "64"), ("resy", "48")],
        &reference,
        32,
        (4, 4),
        512.0 / 8192.0,
        0.01,
    );
}

#[test]
fn bdpt_caustic_matches_mitsuba_light_tracer() {
    // Mitsuba's `ptracer` (65536 light paths per pixel) resolves the glass ball's caustic; it cannot see
    // the ball itself (light tracing never reaches the camera through a Dirac surface), so only the
    // floor in front of the ball is compared: rows 20..32 hold the caustic and the ball's shadow.
    // 2% allows for our tessellated sphere against Mitsuba's analytic one.
    let reference = read_image(&root().join("tests/references/mitsuba/caustic.exr"), false).unwrap();
    let scene = root().join("scenes/caustic/scene.xml");
    let s = load_scene(&scene, &[("resx", "32"), ("resy", "32")]).unwrap();
    let (mean, var) = common::render_runs(&s, IntegratorKind::Bdpt, 64, RUNS, (4, 4));
    let cmp = common::compare(&mean, &var, &reference, (4, 4), 20..32, 0.05, 0.02);
    eprintln!(
        "bdpt caustic floor: flux ratio {:.4}, chi2/dof {:.2} over {} blocks (threshold {:.2})",
        cmp.flux_ratio,
        cmp.chi2_per_dof,
        cmp.blocks,
        runs_threshold()
    );
    assert!(cmp.chi2_per_dof < runs_threshold(), "caustic: chi2/dof {:.2}", cmp.chi2_per_dof);
    assert!((cmp.flux_ratio - 1.0).abs() < 0.03, "caustic: flux ratio {:.4}", cmp.flux_ratio);
}

/// Mitsuba's own error on a reference scene, measured by scripts/make-mitsuba-references.py:
/// independent Mitsuba renders at `spp` against the reference, in `block`-pixel block means.
struct SelfError {
    spp: u32,
    block: usize,
    mean_block_rel_mse: f64,
}

fn mitsuba_self_error(name: &str) -> SelfError {
    let path = root().join(format!("tests/references/mitsuba/{name}.json"));
    let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let e = &meta["self_error"];
    let runs: Vec<f64> = e["block_rel_mse"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    SelfError {
        spp: e["spp"].as_u64().unwrap() as u32,
        block: e["block"].as_u64().unwrap() as usize,
        mean_block_rel_mse: runs.iter().sum::<f64>() / runs.len() as f64,
    }
}

/// Heavy-tailed scenes (light reaching the camera through near-specular glass) defeat the χ² test:
/// a render's own variance estimate misses its rare bright paths. There hslt is called right when its
/// block error is no worse than 1.5× Mitsuba's own at the same sample count (issue 28's tolerance on
/// the path tracer). The runs are averaged first: unbiased noise then falls by their number while a
/// bias does not, which is what makes the test able to fail on a bias (the top face 1.2-1.7× too
/// bright, the failure issue 28 reported, gives 6x6-block relMSE above 1e-2 at any sample count).
fn check_no_worse_than_mitsuba(
    name: &str,
    kind: IntegratorKind,
    runs: u64,
    spp: u32,
    defines: &[(&str, &str)],
) {
    let e = mitsuba_self_error(name);
    let s = load_scene(&root().join(format!("scenes/{name}/scene.xml")), defines).unwrap();
    let reference = read_image(&root().join(format!("tests/references/mitsuba/{name}.exr")), false).unwrap();
    let mut sum: Option<hslt::image::ImageBuf> = None;
    for run in 0..runs {
        let (img, stats) = render_scene(&s, kind, spp, 500 + run);
        assert_eq!(stats.invalid_samples, 0, "{name}: NaN/Inf samples");
        sum = Some(match sum {
            None => img,
            Some(mut acc) => {
                acc.data.iter_mut().zip(&img.data).for_each(|(a, b)| *a += b);
                acc
            }
        });
    }
    let mut mean = sum.unwrap();
    mean.data.iter_mut().for_each(|v| *v /= runs as f32);
    let blocks = |img| hslt::report::metrics::block_means(img, e.block);
    let ours = hslt::report::metrics::compute(&blocks(&mean), &blocks(&reference), 0.01).unwrap().rel_mse;
    // Mitsuba's error scaled to our total sample count (noise variance falls as 1/spp).
    let total = runs as f64 * spp as f64;
    let mitsuba = e.mean_block_rel_mse * e.spp as f64 / total;
    let flux = mean.data.iter().map(|&v| v as f64).sum::<f64>()
        / reference.data.iter().map(|&v| v as f64).sum::<f64>();
    eprintln!(
        "{name} {kind:?}, {runs} x {spp} spp: block relMSE {ours:.2e}, Mitsuba's own at that count {mitsuba:.2e}, \
         flux ratio {flux:.4}"
    );
    assert!(
        ours <= 1.5 * mitsuba,
        "{name} {kind:?}: block relMSE {ours:.2e} > 1.5 x Mitsuba's {mitsuba:.2e}"
    );
}

#[test]
fn nested_rough_glass_no_worse_than_mitsuba() {
    // Issue 28's scene: near-specular glass (Beckmann α = 0.01, ior 1.5) holding rougher tinted water
    // (α = 0.1, 1.33 inside 1.5) over a diffuse floor.
    check_no_worse_than_mitsuba(
        "nested-glass",
        IntegratorKind::Path,
        2,
        4096,
        &[("resx", "48"), ("resy", "36")],
    );
}

#[test]
fn bdpt_nested_rough_glass_no_worse_than_mitsuba() {
    // BDPT resolves the floor caustic under the glass but not the light seen through the top face
    // (paths through two near-specular vertices and a glossy one), so at equal samples it is about
    // as noisy as Mitsuba's path tracer there.
    check_no_worse_than_mitsuba(
        "nested-glass",
        IntegratorKind::Bdpt,
        2,
        2048,
        &[("resx", "48"), ("resy", "36")],
    );
}
