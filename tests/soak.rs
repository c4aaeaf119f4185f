//! Soak test: many small random scenes — random analytic shapes under random, sometimes degenerate
//! transforms (zero and huge scales, collapsed axes), every BSDF with random parameters including
//! α → 0 and α = 1, ior 1 and extreme, all light types including zero-area and zero-radiance ones —
//! each loaded and, when the loader accepts it, rendered by all seven integrators for a few samples.
//! No panic, no non-finite or negative pixel, no render that overruns its time budget. Each scene
//! comes from its own seed; a failure prints it, and `HSLT_SOAK_SEED=<seed>` replays that one scene.
//! `HSLT_SOAK_SCENES=N` runs N scenes instead of the suite's 100 (docs/robustness.md reports longer runs).

use hslt::accel::AccelKind;
use hslt::registry::{make_with, IntegratorKind, IntegratorSettings};
use hslt::render::{DepthLimits, RenderOptions};
use hslt::scene::{LoadOptions, Scene};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

const SCENES_IN_SUITE: u64 = 100;
/// A render of 6×6 pixels at 2 spp that takes longer than this counts as a hang (they take
/// milliseconds; the test cannot interrupt a render that never returns, but CI's timeout would).
const HANG: Duration = Duration::from_secs(20);

fn pick<'a, T>(rng: &mut Pcg64, items: &'a [T]) -> &'a T {
    &items[rng.random_range(0..items.len())]
}

fn number(rng: &mut Pcg64, edge_cases: &[f64], lo: f64, hi: f64) -> f64 {
    if rng.random_bool(0.4) {
        *pick(rng, edge_cases)
    } else {
        rng.random_range(lo..hi)
    }
}

fn bsdf(rng: &mut Pcg64, depth: u32) -> String {
    let alpha = number(rng, &[0.0, 1e-6, 1e-3, 0.01, 1.0], 0.0, 1.0);
    let ior = number(rng, &[1.0, 1.000001, 1.5, 4.0, 100.0], 1.0, 3.0);
    let distribution = pick(rng, &["beckmann", "ggx"]);
    let colour = |rng: &mut Pcg64| {
        let v = number(rng, &[0.0, 1.0], 0.0, 1.0);
        format!("<rgb name=\"reflectance\" value=\"{v}, {}, {}\"/>", rng.random_range(0.0..1.0), v / 2.0)
    };
    let kinds = [
        "diffuse",
        "conductor",
        "roughconductor",
        "dielectric",
        "roughdielectric",
        "plastic",
        "roughplastic",
        "twosided",
    ];
    // twosided takes only BSDFs without transmission (the loader refuses the others).
    let reflective = ["diffuse", "conductor", "roughconductor", "plastic", "roughplastic"];
    let kind = if depth > 0 { pick(rng, &reflective) } else { pick(rng, &kinds) };
    match *kind {
        "diffuse" => format!("<bsdf type=\"diffuse\">{}</bsdf>", colour(rng)),
        "conductor" => "<bsdf type=\"conductor\"/>".to_string(),
        "roughconductor" => format!(
            "<bsdf type=\"roughconductor\"><float name=\"alpha\" value=\"{alpha}\"/>\
             <string name=\"distribution\" value=\"{distribution}\"/></bsdf>"
        ),
        "dielectric" => format!("<bsdf type=\"dielectric\"><float name=\"int_ior\" value=\"{ior}\"/></bsdf>"),
        "roughdielectric" => format!(
            "<bsdf type=\"roughdielectric\"><float name=\"alpha\" value=\"{alpha}\"/>\
             <float name=\"int_ior\" value=\"{ior}\"/><float name=\"ext_ior\" value=\"{}\"/>\
             <string name=\"distribution\" value=\"{distribution}\"/></bsdf>",
            number(rng, &[1.0, 1.5], 1.0, 2.0)
        ),
        "plastic" => format!("<bsdf type=\"plastic\"><float name=\"int_ior\" value=\"{ior}\"/></bsdf>"),
        "roughplastic" => format!(
            "<bsdf type=\"roughplastic\"><float name=\"alpha\" value=\"{alpha}\"/>\
             <float name=\"int_ior\" value=\"{ior}\"/></bsdf>"
        ),
        _ => format!("<bsdf type=\"twosided\">{}</bsdf>", bsdf(rng, depth + 1)),
    }
}

fn transform(rng: &mut Pcg64) -> String {
    let scale = |rng: &mut Pcg64| number(rng, &[1e-7, 1e5], 0.05, 2.0);
    let (mut sx, sy, sz) = (scale(rng), scale(rng), scale(rng));
    // A collapsed axis makes a singular transform, which the loader must refuse (and most scenes
    // should still get past the loader).
    if rng.random_bool(0.03) {
        sx = 0.0;
    }
    let t = |rng: &mut Pcg64| rng.random_range(-2.0..2.0);
    let angle = number(rng, &[0.0, 90.0, 180.0], -180.0, 180.0);
    format!(
        "<transform name=\"to_world\"><scale x=\"{sx}\" y=\"{sy}\" z=\"{sz}\"/>\
         <rotate x=\"{}\" y=\"1\" z=\"{}\" angle=\"{angle}\"/><translate x=\"{}\" y=\"{}\" z=\"{}\"/></transform>",
        t(rng),
        t(rng),
        t(rng),
        t(rng),
        t(rng)
    )
}

/// A random scene: a camera, one to four shapes (some emitting), and other lights.
fn random_scene(seed: u64) -> String {
    let mut rng = Pcg64::seed_from_u64(seed);
    let rng = &mut rng;
    let mut xml = String::from("<scene version=\"3.0.0\">");
    let max_depth = pick(rng, &[-1, 1, 2, 3, 8]);
    let _ = write!(
        xml,
        "<integrator type=\"path\"><integer name=\"max_depth\" value=\"{max_depth}\"/></integrator>"
    );
    let fov = number(rng, &[0.01, 179.0], 10.0, 90.0);
    let _ = write!(
        xml,
        "<sensor type=\"perspective\"><float name=\"fov\" value=\"{fov}\"/><transform name=\"to_world\">\
         <lookat origin=\"{}, {}, 5\" target=\"0, 0, 0\" up=\"0, 1, 0\"/></transform>\
         <film type=\"hdrfilm\"><integer name=\"width\" value=\"6\"/><integer name=\"height\" value=\"6\"/></film></sensor>",
        rng.random_range(-3.0..3.0),
        rng.random_range(-3.0..3.0)
    );
    for _ in 0..rng.random_range(1..=4) {
        let shape = pick(rng, &["rectangle", "sphere", "cube", "disk"]);
        let _ = write!(xml, "<shape type=\"{shape}\">{}{}", transform(rng), bsdf(rng, 0));
        if rng.random_bool(0.4) {
            let radiance = number(rng, &[0.0, 1e6], 0.1, 20.0);
            let _ =
                write!(xml, "<emitter type=\"area\"><rgb name=\"radiance\" value=\"{radiance}\"/></emitter>");
        }
        xml.push_str("</shape>");
    }
    if rng.random_bool(0.5) {
        let _ = write!(
            xml,
            "<emitter type=\"constant\"><rgb name=\"radiance\" value=\"{}\"/></emitter>",
            number(rng, &[0.0], 0.01, 2.0)
        );
    }
    if rng.random_bool(0.3) {
        let _ = write!(
            xml,
            "<emitter type=\"point\"><point name=\"position\" x=\"{}\" y=\"2\" z=\"1\"/><rgb name=\"intensity\" value=\"{}\"/></emitter>",
            rng.random_range(-2.0..2.0),
            number(rng, &[0.0], 1.0, 50.0)
        );
    }
    if rng.random_bool(0.3) {
        let _ = write!(
            xml,
            "<emitter type=\"spot\"><transform name=\"to_world\"><lookat origin=\"0, 3, 3\" target=\"0, 0, 0\"/></transform>\
             <rgb name=\"intensity\" value=\"{}\"/><float name=\"cutoff_angle\" value=\"{}\"/></emitter>",
            number(rng, &[0.0], 1.0, 50.0),
            number(rng, &[0.001, 90.0], 5.0, 60.0)
        );
    }
    xml.push_str("</scene>");
    xml
}

/// Loads and renders one random scene with every integrator; `Err` describes what went wrong.
fn soak_one(seed: u64) -> Result<&'static str, String> {
    let xml = random_scene(seed);
    let options = LoadOptions { defines: Vec::new(), accel: AccelKind::Embree };
    let scene = match std::panic::catch_unwind(|| Scene::load_str(&xml, Path::new("soak.xml"), &options)) {
        Err(_) => return Err(format!("loading panicked\n{xml}")),
        Ok(Err(e)) => {
            if std::env::var_os("HSLT_SOAK_VERBOSE").is_some() {
                eprintln!("seed {seed}: refused: {e:#}");
            }
            return Ok("refused");
        }
        Ok(Ok(scene)) => scene,
    };
    let limits = DepthLimits::of_scene(&scene);
    let mut settings = IntegratorSettings::new(limits, false);
    settings.pssmlt.seed_paths = Some(512);
    settings.pssmlt.chains = 4;
    settings.path_chains = Some(4);
    for kind in IntegratorKind::available_kinds() {
        // No time limit: with one, the Metropolis methods give their direct pass a share of it.
        let render_options = RenderOptions { spp: Some(2), seed, ..Default::default() };
        let start = Instant::now();
        let rendered = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            make_with(kind, &settings).render(&scene, &render_options, &AtomicBool::new(false))
        }));
        let elapsed = start.elapsed();
        if std::env::var_os("HSLT_SOAK_VERBOSE").is_some() {
            eprintln!("seed {seed}: {} {elapsed:?}", kind.name());
        }
        let out = rendered.map_err(|_| format!("{} panicked\n{xml}", kind.name()))?;
        if elapsed >= HANG {
            return Err(format!("{} ran {elapsed:?} on 6x6 pixels at 2 spp\n{xml}", kind.name()));
        }
        let image = out.film.to_image();
        if let Some(v) = image.data.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(format!("{} wrote the pixel value {v}\n{xml}", kind.name()));
        }
    }
    Ok("rendered")
}

#[test]
fn random_scenes_load_or_fail_cleanly_and_render_finite_images() {
    let seeds: Vec<u64> = match std::env::var("HSLT_SOAK_SEED") {
        Ok(s) => vec![s.parse().expect("HSLT_SOAK_SEED is a number")],
        Err(_) => {
            let n = std::env::var("HSLT_SOAK_SCENES")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(SCENES_IN_SUITE);
            (0..n).map(|i| 0x5eed_0000 + i).collect()
        }
    };
    let (mut rendered, mut refused) = (0, 0);
    let mut failures = Vec::new();
    for &seed in &seeds {
        match soak_one(seed) {
            Ok("rendered") => rendered += 1,
            Ok(_) => refused += 1,
            Err(e) => failures.push(format!("seed {seed} (HSLT_SOAK_SEED={seed}): {e}")),
        }
    }
    eprintln!(
        "soak: {} scenes, {rendered} rendered by every integrator, {refused} refused by the loader",
        seeds.len()
    );
    assert!(
        failures.is_empty(),
        "{} of {} scenes failed:\n{}",
        failures.len(),
        seeds.len(),
        failures.join("\n\n")
    );
    // Most scenes must get past the loader, or the soak tests only the error paths.
    assert!(
        seeds.len() < 10 || rendered * 2 > seeds.len(),
        "only {rendered} of {} scenes rendered",
        seeds.len()
    );
}
