//! Direct illumination rendered apart from the Metropolis chains, as Mitsuba's MLT family does by
//! default (`directSamples`, which the HSLT paper's comparisons inherit): paths of one or two segments
//! (emitters seen directly, one-bounce lighting) are estimated by BDPT restricted to them and to light
//! sub-paths of one vertex, and the chains spend all their mutations on indirect light. PSSMLT does so
//! by default, and so do the path-space methods whose mixture has a large step
//! (`DirectPass::for_path_space` says why).

use crate::integrators::Bdpt;
use crate::render::{self, Film, RenderOptions, RenderStats};
use crate::scene::Scene;
use std::sync::atomic::AtomicBool;

/// Vertices of the shortest path the chains keep when direct illumination is rendered separately:
/// camera, two scattering vertices, emitter.
pub const CHAIN_MIN_VERTICES: usize = 4;

/// Samples per pixel of the direct pass of a render without a time limit (Mitsuba's default).
pub const DEFAULT_DIRECT_SAMPLES: u32 = 16;

/// Share of a time limit the direct pass gets by default. A fixed 16 samples per pixel is too few
/// for an equal-time comparison: on the jewelry scene (128×96) they take 0.2 s and alone leave a
/// relative MSE of 6e-3, twice what PSSMLT reaches in 60 s over the whole image.
pub const DEFAULT_DIRECT_SHARE: f64 = 0.1;

/// How the direct-illumination pass is sized (CLI: `--direct-samples`, `--direct-share`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DirectPass {
    /// No separate pass: the chains render direct illumination too.
    Off,
    /// This many samples per pixel.
    Samples(u32),
    /// This fraction of the render's time limit (`Samples(DEFAULT_DIRECT_SAMPLES)` without one).
    Share(f64),
    /// Each integrator's default: for PSSMLT `Share(DEFAULT_DIRECT_SHARE)` with a time limit and
    /// `Samples(DEFAULT_DIRECT_SAMPLES)` without; the same for the path-space methods with a large
    /// step in their mixture, `Off` for the others (`for_path_space`).
    Auto,
}

impl DirectPass {
    /// The pass a path-space method runs. `Auto` runs it when the mixture has a large step
    /// (`refines_b`) and is off otherwise. With the pass the chains' b covers indirect light alone,
    /// which is far more heavy-tailed than the whole image, and a seeding pass alone estimates it
    /// poorly: on the caustic scene, with 65 536 seed paths, lens-only chains came out 3.6% dark
    /// (0.0739 ± 0.0004 against BDPT's 0.0767 ± 0.0011 over 16 runs). Every large step's f(y)/p(y)
    /// refines b as PSSMLT's large steps do, and with both the path-space methods' relative MSE on the
    /// rings of the jewelry scene fell 2.5–10× (docs/benchmarks.md, session 8).
    pub fn for_path_space(self, refines_b: bool) -> DirectPass {
        if self == DirectPass::Auto && !refines_b {
            DirectPass::Off
        } else {
            self
        }
    }

    pub fn enabled(self) -> bool {
        match self {
            DirectPass::Off | DirectPass::Samples(0) => false,
            // A share of nothing would leave direct light to nobody.
            DirectPass::Share(f) => f > 0.0,
            DirectPass::Samples(_) | DirectPass::Auto => true,
        }
    }

    /// Samples per pixel (a cap, `None` = unbounded) and time budget of the pass in a render with
    /// `options`.
    fn budget(self, options: &RenderOptions) -> (Option<u32>, Option<std::time::Duration>) {
        let share = match (self, options.time_limit) {
            (DirectPass::Off, _) => return (Some(0), None),
            (DirectPass::Samples(n), _) => return (Some(n), None),
            (DirectPass::Share(f), Some(_)) => f,
            (DirectPass::Auto, Some(_)) => DEFAULT_DIRECT_SHARE,
            (DirectPass::Share(_) | DirectPass::Auto, None) => return (Some(DEFAULT_DIRECT_SAMPLES), None),
        };
        let limit = options.time_limit.map(|t| t.mul_f64(share.clamp(0.0, 1.0)));
        (None, limit)
    }
}

/// Mixed into the seed so the direct pass never shares random numbers with the seeding pass or the
/// chains (whose streams derive from the same seed).
const DIRECT_SEED: u64 = 0xD1EC_7000_0000_0001;

/// The BDPT the chains and the seeding pass run on: `bdpt` itself, or with paths shorter than
/// `CHAIN_MIN_VERTICES` left to the direct pass when it is enabled.
pub fn chain_bdpt(mut bdpt: Bdpt, direct: DirectPass) -> Bdpt {
    if direct.enabled() {
        bdpt.min_path_vertices = bdpt.min_path_vertices.max(CHAIN_MIN_VERTICES);
        bdpt.strategy_layers = None;
    }
    bdpt
}

/// Renders the paths the chains leave out (`chain_bdpt`) for the budget `pass` gives and adds them to
/// `film` as one sample per pixel, so the chains' splats land on top. Adds its rays and invalid
/// samples to `stats` and its sample count and time to `metadata`; nothing is rendered when the pass
/// is off or the chains keep every path. Its time counts against the render's time limit.
///
/// The estimator is BDPT with light sub-paths of one vertex (`Bdpt::max_light_vertices`): the path
/// tracer's strategies (emitters hit, light sampling) plus the light seen directly through a
/// connection to the camera (s = 1, t = 1). Full BDPT's longer light sub-paths add almost nothing for
/// paths this short and cost a light walk per sample: on the rings scene (128×96, 6 s, 3 seeds) it
/// left a relative MSE of 4.7e-4 against 2.7e-4 with the cap, and with it the pass was the larger part
/// of every Metropolis method's error in a 60-s render. The path tracer alone left 1.2e-4 there, but
/// ten times the cap's error on the Cornell box, whose light it sees only by hitting it
/// (docs/benchmarks.md, sessions 9–10).
#[allow(clippy::too_many_arguments)]
pub fn render_into(
    film: &mut Film,
    scene: &Scene,
    chain_bdpt: &Bdpt,
    pass: DirectPass,
    options: &RenderOptions,
    cancel: &AtomicBool,
    stats: &mut RenderStats,
    metadata: &mut Vec<(String, String)>,
) {
    let (samples, time_limit) = pass.budget(options);
    if !pass.enabled() || chain_bdpt.min_path_vertices <= 2 {
        return;
    }
    let below = chain_bdpt.min_path_vertices as i32 - 2;
    let max_depth =
        if chain_bdpt.limits.max_depth < 0 { below } else { chain_bdpt.limits.max_depth.min(below) };
    let mut direct = chain_bdpt.clone();
    direct.limits.max_depth = max_depth;
    direct.min_path_vertices = 2;
    direct.max_light_vertices = 1;
    let direct_options = RenderOptions {
        spp: samples,
        time_limit,
        seed: options.seed ^ DIRECT_SEED,
        progress: false,
        snapshots: None,
        // A run continuing one of N mutations per pixel (first_sample = N >= 1) starts past the
        // `samples` indices the earlier run's direct pass used.
        first_sample: options.first_sample.saturating_mul(samples.unwrap_or(1 << 16)),
    };
    let (direct_film, direct_stats) = render::render(scene, &direct, &direct_options, cancel);
    film.add_image_as_sample(&direct_film.to_image());
    stats.rays += direct_stats.rays;
    stats.invalid_samples += direct_stats.invalid_samples;
    metadata.push(("hslt.mlt.direct_samples".into(), direct_stats.min_spp.to_string()));
    metadata.push(("hslt.mlt.seconds_direct".into(), format!("{:.3}", direct_stats.elapsed.as_secs_f64())));
}
