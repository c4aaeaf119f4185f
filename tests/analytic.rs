//! Analytic integrator tests (pbrt-v4's integrators_test.cpp is the model): scenes whose exact pixel
//! value is known. Every pixel of these scenes has the same expectation, so the spread of pixel
//! values gives the standard error of the image mean, and each check allows 5 standard errors
//! (a false failure about once in 1.7 million runs) plus float round-off.
//! Every integrator joins this suite as it lands (`IntegratorKind::available_kinds`).

use hslt::cli::{load_scene, render_scene};
use hslt::image::ImageBuf;
use hslt::registry::IntegratorKind;
use std::path::Path;

/// Mean and standard error of the mean over all channels of all pixels.
fn mean_and_stderr(img: &ImageBuf) -> (f64, f64) {
    let n = img.data.len() as f64;
    let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = img.data.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0);
    // Channels of one pixel are correlated (grey scenes): count pixels, not channels.
    let pixels = (img.width * img.height) as f64;
    (mean, (var / pixels).sqrt())
}

fn assert_converges(scene: &str, defines: &[(&str, &str)], spp: u32, expected: f64) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(scene);
    let scene_data = load_scene(&path, defines).unwrap_or_else(|e| panic!("{scene}: {e:#}"));
    for kind in IntegratorKind::available_kinds() {
        let (img, stats) = render_scene(&scene_data, kind, spp, 11);
        assert_eq!(stats.invalid_samples, 0, "{scene} {defines:?}: NaN/Inf samples");
        assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0));
        let (mean, se) = mean_and_stderr(&img);
        let tol = 5.0 * se + 1e-4 * expected.abs() + 1e-6;
        assert!(
            (mean - expected).abs() <= tol,
            "{} on {scene} {defines:?}: mean {mean:.5}, expected {expected:.5} ± {tol:.5}",
            kind.name()
        );
    }
}

#[test]
fn camera_inside_emitting_reflecting_sphere() {
    // Le / (1 - rho) = 0.5 / 0.5.
    assert_converges("tests/data/analytic/inside-sphere.xml", &[], 64, 1.0);
    assert_converges("tests/data/analytic/inside-sphere.xml", &[("rho", "0.8"), ("le", "0.2")], 64, 1.0);
}

#[test]
fn max_depth_counts_segments_as_mitsuba_does() {
    // max_depth = k keeps paths of up to k segments: Le * (1 + rho + ... + rho^(k-1)).
    for (k, expected) in [("1", 0.5), ("2", 0.75), ("3", 0.875)] {
        assert_converges("tests/data/analytic/inside-sphere.xml", &[("max_depth", k)], 32, expected);
    }
}

#[test]
fn diffuse_plane_under_constant_sky() {
    assert_converges("tests/data/analytic/plane-under-sky.xml", &[], 32, 0.5 * 2.0);
    assert_converges("tests/data/analytic/plane-under-sky.xml", &[("rho", "0.9")], 32, 0.9 * 2.0);
    assert_converges("tests/data/analytic/plane-under-sky.xml", &[("max_depth", "1")], 4, 0.0);
}

#[test]
fn results_do_not_depend_on_scene_scale() {
    // The same plane scaled to a millimetre and to a thousand kilometres: ray offsets must scale.
    for scale in ["0.001", "1000"] {
        assert_converges("tests/data/analytic/plane-under-sky.xml", &[("scale", scale)], 16, 1.0);
    }
}

#[test]
fn white_furnace_diffuse() {
    // Albedo 1: the sphere is invisible against the sky; albedo 0.5 darkens only the sphere's pixels,
    // so check the exact value where the sphere covers the pixel centre region instead.
    assert_converges("scenes/furnace/diffuse.xml", &[], 16, 1.0);
}

#[test]
fn white_furnace_rough_conductor_loses_but_never_gains_energy() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/furnace/roughconductor.xml");
    for (alpha, lower) in [("0.05", 0.97), ("0.3", 0.9), ("0.8", 0.75)] {
        let scene = load_scene(&path, &[("alpha", alpha)]).unwrap();
        for kind in IntegratorKind::available_kinds() {
            let (img, _) = render_scene(&scene, kind, 64, 5);
            let (mean, se) = mean_and_stderr(&img);
            assert!(mean <= 1.0 + 5.0 * se + 1e-4, "alpha {alpha}: furnace mean {mean} gains energy");
            assert!(mean >= lower, "alpha {alpha}: furnace mean {mean} loses more than expected (< {lower})");
        }
    }
}
