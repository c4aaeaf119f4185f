//! The scenes authored for the paper's experiments load, take their parameters, and render to a
//! finite image with light in it (at a tiny size, with the path tracer).

use hslt::registry::IntegratorKind;
use std::path::Path;

fn render(scene: &str, defines: &[(&str, &str)]) -> hslt::image::ImageBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(scene).join("scene.xml");
    let mut all = vec![("resx", "24"), ("resy", "18")];
    all.extend_from_slice(defines);
    let scene = hslt::cli::load_scene(&path, &all).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
    assert!(scene.warnings.is_empty(), "{}: {:?}", path.display(), scene.warnings);
    let (img, _) = hslt::cli::render_scene(&scene, IntegratorKind::Path, 4, 1);
    assert_eq!(img.count_non_finite(), 0);
    let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64;
    assert!(mean > 1e-3, "{scene:?}: image is black (mean {mean})", scene = path.display());
    img
}

#[test]
fn experiment_scenes_load_and_render() {
    for scene in ["fig15", "fig17", "jewelry"] {
        render(scene, &[]);
    }
}

#[test]
fn fig15_roughness_is_a_parameter() {
    assert_ne!(render("fig15", &[]), render("fig15", &[("roughness", "0.1")]));
}
