//! Scale invariance of every integrator: the stability case 13 scene (a rough metal floor and sphere
//! under a small area light) built at 1e-3, 1 and 1e3 times its size has the same image, since radiance
//! does not depend on units. Rendered with the same seed, the three renders trace the same paths up to
//! rounding, so any absolute epsilon (ray offsets, distance thresholds, density clamps) shows up as a
//! difference far beyond their noise. Issue 28 asks for the flux within ±1% for every integrator; this
//! test holds them to ±0.5%.

use hslt::cli::render_scene;
use hslt::registry::IntegratorKind;
use hslt::scene::{LoadOptions, Scene};
use std::path::Path;

fn scene_at(scale: f64) -> Scene {
    let xml = hslt::stability::scale_case_scene(scale);
    Scene::load_str(&xml, Path::new(&format!("scale-{scale:e}.xml")), &LoadOptions::default()).unwrap()
}

fn flux(scene: &Scene, kind: IntegratorKind) -> f64 {
    let (img, stats) = render_scene(scene, kind, 128, 7);
    assert_eq!(stats.invalid_samples, 0, "{kind:?}: NaN/Inf samples");
    img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64
}

#[test]
fn every_integrator_renders_the_same_flux_at_every_scale() {
    let scenes: Vec<(f64, Scene)> = [1e-3, 1.0, 1e3].into_iter().map(|s| (s, scene_at(s))).collect();
    let mut failures = Vec::new();
    for kind in IntegratorKind::available_kinds() {
        let fluxes: Vec<f64> = scenes.iter().map(|(_, scene)| flux(scene, kind)).collect();
        for (i, (scale, _)) in scenes.iter().enumerate() {
            let ratio = fluxes[i] / fluxes[1];
            eprintln!("{}: scale {scale:e}, flux {:.5}, ratio to scale 1 {ratio:.4}", kind.name(), fluxes[i]);
            // The renders agree to 1e-4 (PSSMLT to 1e-3, its chains diverge by rounding); the old absolute
            // ray-offset floor moved them by 0.6% (BDPT) to 4.3% (PSSMLT) at 1e-3.
            if (ratio - 1.0).abs() > 0.005 {
                failures.push(format!("{} at scale {scale:e}: flux ratio {ratio:.4}", kind.name()));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("; "));
}
