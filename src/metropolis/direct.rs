//! Direct illumination rendered apart from the Metropolis chains, as Mitsuba's MLT family does by
//! default (`directSamples`, which the HSLT paper's comparisons inherit): paths of one or two segments
//! (emitters seen directly, one-bounce lighting) get a pass of their own, and the chains spend all
//! their mutations on indirect light. PSSMLT does so by default, and so do the path-space methods
//! whose mixture has a large step (`DirectPass::for_path_space` says why).

use crate::integrators::{Bdpt, PathTracer};
use crate::render::{self, DepthLimits, Film, RenderOptions, RenderStats};
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
    /// The pass a path-space method runs. `Auto` runs it when the mixture has a large step and is off
    /// otherwise. With the pass the chains' b covers indirect light alone, which is far more
    /// heavy-tailed than the whole image: on the caustic scene, with 65 536 seed paths, lens-only
    /// chains came out 3.6% dark (0.0739 ± 0.0004 against BDPT's 0.0767 ± 0.0011 over 16 runs). The
    /// large steps then refined b, and with both the path-space methods' relative MSE on the rings of
    /// the jewelry scene fell 2.5–10× (docs/mlt-sessions.md, session 8). b now comes from a seeding
    /// pass long enough on its own (`metropolis::normalization`); the rule was not re-measured since.
    pub fn for_path_space(self, has_large_step: bool) -> DirectPass {
        if self == DirectPass::Auto && !has_large_step {
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

/// Share of the direct pass's time for the emitters seen directly (its second part, `render_into`).
/// Its samples cost about as much as the path tracer's (rings: 360 and 1 442 samples per pixel in 1.2
/// and 4.8 s), and where no emitter is in view the share is lost: a fifth raised the rings' direct
/// error from the path tracer's 1.2e-4 to 1.4e-4. Not tuned further.
pub const SEEN_SHARE: f64 = 0.2;

/// Mixed into the direct pass's seed for its second part.
const SEEN_SEED: u64 = 0x5EE2;

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
/// The pass has two parts. One-bounce light (three vertices) is the path tracer's (light sampling and
/// BSDF sampling under MIS) with emitters seen directly left out; those (two vertices) are BDPT's
/// strategies for them, the camera ray that hits the emitter and the emitter's points joined to the
/// camera (s = 1, t = 1), in `SEEN_SHARE` of the time. Full BDPT's longer light sub-paths add almost
/// nothing for paths this short and cost a light walk per sample: on the rings scene (128×96, direct
/// light alone, 6 s, 3 seeds) it left a relative MSE of 4.7e-4 against 1.4e-4 with these two parts,
/// and with it the pass was the larger part of every Metropolis method's error in a 60-s render. The
/// path tracer alone (1.2e-4 there) sees a light's edges only by hitting the light: on the Cornell
/// box at 32×32 it left ten times BDPT's error, which the second part removes (docs/mlt-sessions.md,
/// sessions 9–10).
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
    let seed = options.seed ^ DIRECT_SEED;
    let pass_options = |seed: u64, share: f64| RenderOptions {
        spp: samples,
        time_limit: time_limit.map(|t| t.mul_f64(share)),
        seed,
        progress: false,
        snapshots: None,
        // A run continuing one of N mutations per pixel (first_sample = N >= 1) starts past the
        // `samples` indices the earlier run's direct pass used.
        first_sample: options.first_sample.saturating_mul(samples.unwrap_or(1 << 16)),
        // A share of the render (`--part`) takes its share of the pass's sample indices.
        share: options.share,
        mutations_done: 0,
    };
    // One-bounce light (three vertices): the path tracer, emitters seen directly left out.
    let lit = PathTracer {
        limits: DepthLimits { max_depth, ..chain_bdpt.limits },
        hide_emitters: true,
        min_depth: 1,
    };
    let seen_share = if chain_bdpt.hide_emitters { 0.0 } else { SEEN_SHARE };
    let (lit_film, lit_stats) = render::render(scene, &lit, &pass_options(seed, 1.0 - seen_share), cancel);
    let mut image = lit_film.to_image();
    stats.rays += lit_stats.rays;
    stats.shadow_rays += lit_stats.shadow_rays;
    stats.invalid_samples += lit_stats.invalid_samples;
    let mut elapsed = lit_stats.elapsed;
    metadata.push(("hslt.mlt.direct_samples".into(), lit_stats.min_spp.to_string()));
    if seen_share > 0.0 {
        // Emitters seen directly (two vertices): the camera ray that hits one and the emitter's points
        // joined to the camera (s = 1, t = 1), under MIS.
        let mut seen = chain_bdpt.clone();
        seen.limits.max_depth = 1;
        seen.min_path_vertices = 2;
        seen.max_light_vertices = 1;
        let (seen_film, seen_stats) =
            render::render(scene, &seen, &pass_options(seed ^ SEEN_SEED, seen_share), cancel);
        let seen_image = seen_film.to_image();
        for (a, b) in image.data.iter_mut().zip(&seen_image.data) {
            *a += *b;
        }
        stats.rays += seen_stats.rays;
        stats.shadow_rays += seen_stats.shadow_rays;
        stats.invalid_samples += seen_stats.invalid_samples;
        elapsed += seen_stats.elapsed;
        metadata.push(("hslt.mlt.direct_seen_samples".into(), seen_stats.min_spp.to_string()));
    }
    // Weighted by its samples, so merged renders (`render::RenderState`) weight their passes by work.
    film.add_image_as_samples(&image, lit_stats.min_spp as u64);
    metadata.push(("hslt.mlt.seconds_direct".into(), format!("{:.3}", elapsed.as_secs_f64())));
}
