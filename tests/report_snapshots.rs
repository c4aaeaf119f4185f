//! The snapshot hook of the render loop: called after the pass during which each requested time
//! passed, once per time at most, and each snapshot is exactly the image a render stopped there gives.

use hslt::registry::{self, IntegratorKind};
use hslt::render::{DepthLimits, RenderOptions, Snapshot, SnapshotHook};
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The two tests below measure wall time against their own snapshot times; run side by side they take
/// each other's cores (the test harness runs a file's tests in parallel), so they take turns.
static TIMED: Mutex<()> = Mutex::new(());

fn scene() -> hslt::scene::Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    hslt::cli::load_scene(&path, &[("resx", "32"), ("resy", "24")]).unwrap()
}

#[test]
fn snapshots_arrive_after_their_times_and_match_a_render_of_that_many_samples() {
    let _turn = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let scene = scene();
    let limits = DepthLimits::of_scene(&scene);
    let integrator = registry::make(IntegratorKind::Path, limits, false);
    let taken: Arc<Mutex<Vec<Snapshot>>> = Arc::default();
    let sink = {
        let taken = taken.clone();
        move |s: &Snapshot| taken.lock().unwrap().push(s.clone())
    };
    let times: Vec<Duration> = [0.02, 0.05, 0.1, 0.2, 0.4].into_iter().map(Duration::from_secs_f64).collect();
    let options = RenderOptions {
        time_limit: Some(Duration::from_millis(600)),
        seed: 5,
        snapshots: Some(SnapshotHook::images(times.clone(), sink)),
        ..Default::default()
    };
    let output = integrator.render(&scene, &options, &AtomicBool::new(false));
    let taken = taken.lock().unwrap();
    assert!(
        taken.len() >= 3 && taken.len() <= times.len(),
        "{} snapshots for {} times",
        taken.len(),
        times.len()
    );
    assert!(taken[0].elapsed >= times[0]);
    for w in taken.windows(2) {
        assert!(w[1].elapsed > w[0].elapsed && w[1].spp > w[0].spp && w[1].samples > w[0].samples);
    }
    let last = taken.last().unwrap();
    assert!(last.elapsed <= output.stats.elapsed && last.spp <= output.stats.min_spp);
    // Passes are shortened near snapshot times, so none lands far after its time.
    for s in taken.iter() {
        let requested = times.iter().rev().find(|&&t| t <= s.elapsed).unwrap();
        assert!(
            s.elapsed < *requested + Duration::from_millis(250),
            "snapshot at {:?} for {requested:?}",
            s.elapsed
        );
    }
    // Deterministic streams: a snapshot at k spp is the image of a plain k-spp render.
    let s = &taken[1];
    assert_eq!(s.samples, s.spp as u64 * 32 * 24);
    let (plain, _) = hslt::cli::render_scene(&scene, IntegratorKind::Path, s.spp, 5);
    assert_eq!(s.image, plain, "snapshot at {} spp differs from a {} spp render", s.spp, s.spp);
}

#[test]
fn first_sample_continues_the_streams() {
    let scene = scene();
    let limits = DepthLimits::of_scene(&scene);
    let integrator = registry::make(IntegratorKind::Path, limits, false);
    let never = AtomicBool::new(false);
    let render = |spp, first_sample| {
        let options = RenderOptions { spp: Some(spp), seed: 9, first_sample, ..Default::default() };
        integrator.render(&scene, &options, &never).film.to_image()
    };
    let (a, b, both) = (render(2, 0), render(3, 2), render(5, 0));
    let mut worst = 0.0f32;
    for ((x, y), z) in a.data.iter().zip(&b.data).zip(&both.data) {
        worst = worst.max(((2.0 * x + 3.0 * y) / 5.0 - z).abs() / (1e-3 + z));
    }
    assert!(worst < 1e-5, "2 + 3 spp differ from 5 spp by {worst}");
    assert_ne!(b, render(3, 0), "first_sample had no effect");
}

/// Metropolis chains run in rounds that end at snapshot times: the hook is called, with growing
/// mutation counts and an acceptance rate, and the last snapshot is close to the final image.
#[test]
fn metropolis_chains_take_snapshots_between_rounds() {
    let _turn = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let scene = scene();
    let limits = DepthLimits::of_scene(&scene);
    let mut settings = registry::IntegratorSettings::new(limits, false);
    settings.pssmlt.seed_paths = Some(4096);
    settings.pssmlt.chains = 8;
    let integrator = registry::make_with(IntegratorKind::Pssmlt, &settings);
    let taken: Arc<Mutex<Vec<Snapshot>>> = Arc::default();
    let sink = {
        let taken = taken.clone();
        move |s: &Snapshot| taken.lock().unwrap().push(s.clone())
    };
    let times: Vec<Duration> = [0.3, 0.6, 0.9].into_iter().map(Duration::from_secs_f64).collect();
    let options = RenderOptions {
        time_limit: Some(Duration::from_millis(1500)),
        seed: 5,
        snapshots: Some(SnapshotHook::images(times.clone(), sink)),
        ..Default::default()
    };
    let output = integrator.render(&scene, &options, &AtomicBool::new(false));
    let taken = taken.lock().unwrap();
    assert!(!taken.is_empty() && taken.len() <= times.len(), "{} snapshots", taken.len());
    for w in taken.windows(2) {
        assert!(w[1].elapsed > w[0].elapsed && w[1].samples > w[0].samples);
    }
    for s in taken.iter() {
        let requested = times.iter().rev().find(|&&t| t <= s.elapsed).unwrap();
        assert!(s.elapsed < *requested + Duration::from_millis(400), "snapshot at {:?}", s.elapsed);
        let rate: f64 = s.extra.iter().find(|(k, _)| k == "acceptance_rate").unwrap().1.parse().unwrap();
        assert!(rate > 0.0 && rate <= 1.0);
        assert!(s.samples <= output.stats.samples);
    }
    let mean =
        |img: &hslt::image::ImageBuf| img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64;
    let last = taken.last().unwrap();
    let final_mean = mean(&output.film.to_image());
    assert!(
        (mean(&last.image) - final_mean).abs() < 0.2 * final_mean,
        "last snapshot mean {} vs final {final_mean}",
        mean(&last.image)
    );
}
