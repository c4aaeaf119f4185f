//! The render loop shared by all pixel integrators: passes of samples over 16×16 tiles in parallel,
//! per-pixel random streams keyed by (seed, pixel, sample index), and accumulation in a fixed order,
//! so the same seed and sample count give the same image for any thread count. A time budget, a
//! cancellation flag (Ctrl-C) and a progress bar sit here, outside the integrators, and so does the
//! snapshot hook that every integrator (pixel or Metropolis) calls to show its image at requested times.

mod film;
mod integrator;
mod state;

pub use film::{Film, Splat};
pub use integrator::{
    DepthLimits, Integrator, PixelIntegrator, RenderOutput, SampleCounters, SampleOutput, TiledRenderer,
};
pub use state::{RenderState, Work, MEAN_LAYER, SPLAT_LAYER};

use crate::image::ImageBuf;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

const TILE: usize = 16;

/// How long and how densely to render. `..Default::default()` fills the fields a caller does not
/// care about (no budget: the scene's sample count; seed 0; no progress bar, snapshots or offset).
#[derive(Clone, Debug, Default)]
pub struct RenderOptions {
    /// Samples per pixel to take in this run (the cap when a time budget is also given).
    pub spp: Option<u32>,
    /// Wall-clock budget.
    pub time_limit: Option<Duration>,
    pub seed: u64,
    /// Show a progress bar (only drawn on a terminal).
    pub progress: bool,
    /// Called with the image so far at requested times (error-against-time reports, checkpoints).
    pub snapshots: Option<SnapshotHook>,
    /// Index of this run's first sample in every pixel's random stream: a run that continues an
    /// earlier one of N spp passes N, so the two together take exactly the samples of one run of
    /// N + M spp. Integrators without per-pixel sample indices (Metropolis chains) must still make
    /// runs with different offsets statistically independent, e.g. by mixing it into their seeds.
    pub first_sample: u32,
    /// The share of the work this run does (`hslt render --part K/N`): pixel integrators take their
    /// share of each pixel's sample indices (of a time-limited render: streams of their own), the
    /// Metropolis ones their share of seed samples, chains and mutations, so the shares together are
    /// one render (`RenderState::absorb`).
    pub share: Share,
    /// Mutations an earlier run of this render already did: a resumed Metropolis render with a fixed
    /// amount of work (`spp`) runs only the rest.
    pub mutations_done: u64,
}

/// The K-th of N disjoint shares of a render's work (0-based here; the CLI counts from 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Share {
    pub index: u32,
    pub count: u32,
}

impl Default for Share {
    fn default() -> Share {
        Share::WHOLE
    }
}

impl Share {
    pub const WHOLE: Share = Share { index: 0, count: 1 };

    pub fn is_whole(self) -> bool {
        self.count <= 1
    }

    /// This share's part of the indices `0..n`: consecutive, and the shares of one `count` tile `0..n`.
    pub fn range(self, n: u64) -> std::ops::Range<u64> {
        let count = self.count.max(1) as u128;
        let at = |k: u128| (n as u128 * k / count) as u64;
        at(self.index as u128)..at(self.index as u128 + 1)
    }

    /// A seed for this share's own random streams, where the work cannot be split by index (a time
    /// limit leaves the number of samples open); the whole render keeps `seed` itself.
    pub fn stream_seed(self, seed: u64) -> u64 {
        if self.is_whole() {
            seed
        } else {
            seed ^ (0x5AA7_E000_0000_0000 | (self.index as u64) << 16 | self.count as u64)
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        }
    }
}

/// The state of a render at one moment, handed to a [`SnapshotHook`].
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// Wall time since the integrator's `render` started.
    pub elapsed: Duration,
    /// The image the render would return if it stopped now (same normalisation as the final film).
    pub image: ImageBuf,
    /// Work done so far: camera samples for pixel integrators, proposed mutations for Metropolis.
    pub samples: u64,
    /// Samples per pixel every pixel has reached (0 for integrators without that notion).
    pub spp: u32,
    /// Integrator-specific statistics, e.g. `("acceptance_rate", "0.41")` (a number in [0, 1]).
    pub extra: Vec<(String, String)>,
    /// The film and its work, when the hook asks for them (`SnapshotHook::with_state`): what a
    /// checkpoint saves.
    pub state: Option<RenderState>,
}

/// Asks an integrator for snapshots of its image at given wall times.
///
/// Contract, for the tile loop here and for every integrator with its own loop (Metropolis chains):
/// - `times` are offsets from the start of `Integrator::render`, ascending; the integrator keeps its
///   units of work (passes, mutation batches) short enough that it checks the clock near each time.
/// - After the unit of work during which a requested time passed, it calls `sink` once with the image
///   so far; when one unit passes several times, one call stands for all of them. Use
///   [`SnapshotClock`], which does this bookkeeping.
/// - `sink` runs on the rendering thread while the render waits, so it should be quick; its time
///   counts against the render's budget, equally for every integrator.
/// - Times after the render stops (time limit, sample target, cancellation) produce no call: the
///   caller has the final `RenderOutput` for that moment.
#[derive(Clone)]
pub struct SnapshotHook {
    pub times: Vec<Duration>,
    pub sink: Arc<dyn Fn(&Snapshot) + Send + Sync>,
    /// Whether snapshots carry a copy of the film (`Snapshot::state`), which costs a copy of it.
    pub with_state: bool,
}

impl SnapshotHook {
    /// Snapshots of the image alone at `times`.
    pub fn images(times: Vec<Duration>, sink: impl Fn(&Snapshot) + Send + Sync + 'static) -> SnapshotHook {
        SnapshotHook { times, sink: Arc::new(sink), with_state: false }
    }
}

impl std::fmt::Debug for SnapshotHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SnapshotHook").field("times", &self.times).finish_non_exhaustive()
    }
}

/// Keeps track of which requested snapshot times have been served, for integrator loops.
#[derive(Debug)]
pub struct SnapshotClock<'a> {
    hook: Option<&'a SnapshotHook>,
    next: usize,
}

impl<'a> SnapshotClock<'a> {
    pub fn new(options: &'a RenderOptions) -> SnapshotClock<'a> {
        SnapshotClock { hook: options.snapshots.as_ref(), next: 0 }
    }

    /// Whether the snapshots should carry the film (`Snapshot::state`).
    pub fn wants_state(&self) -> bool {
        self.hook.is_some_and(|h| h.with_state)
    }

    /// The next requested time not yet served, so loops can end a unit of work close to it.
    pub fn next_time(&self) -> Option<Duration> {
        self.hook.and_then(|h| h.times.get(self.next).copied())
    }

    /// Calls the sink with `make()` when a requested time has passed by `elapsed` (once for all the
    /// times passed since the last call); `make` only runs then, so resolving the image is free
    /// otherwise.
    pub fn poll(&mut self, elapsed: Duration, make: impl FnOnce() -> Snapshot) {
        let Some(hook) = self.hook else { return };
        let passed = hook.times[self.next..].iter().take_while(|&&t| t <= elapsed).count();
        if passed > 0 {
            self.next += passed;
            (hook.sink)(&make());
        }
    }
}

/// What happened during a render.
#[derive(Clone, Debug, Default)]
pub struct RenderStats {
    /// Samples added to the film.
    pub samples: u64,
    /// Samples whose estimate was NaN or infinite; they are dropped, never averaged in.
    pub invalid_samples: u64,
    pub rays: u64,
    /// Of `rays`, the shadow rays (the rest are closest-hit queries).
    pub shadow_rays: u64,
    pub elapsed: Duration,
    /// Complete passes over the image.
    pub passes: u32,
    /// Sample count every pixel has reached.
    pub min_spp: u32,
    pub interrupted: bool,
}

/// Renders `scene` with a pixel integrator. Stops at the sample target, the time limit or when
/// `cancel` is set, whichever comes first, and returns the film with everything finished so far.
pub fn render(
    scene: &Scene,
    integrator: &dyn PixelIntegrator,
    options: &RenderOptions,
    cancel: &AtomicBool,
) -> (Film, RenderStats) {
    let (width, height) = (scene.film.width, scene.film.height);
    let mut film = Film::with_filter(width, height, scene.film.rfilter);
    for name in integrator.layers() {
        film.add_layer(name);
    }
    let splats = integrator.splats();
    // Splat lists are held for a whole pass; about a million per pass bounds their memory.
    let max_pass = if splats { ((1usize << 20) / (width * height).max(1)).clamp(1, 64) as u32 } else { 64 };
    let tiles = tile_grid(width, height);
    let start = Instant::now();
    let target = match (options.spp, options.time_limit) {
        (Some(n), _) => Some(n.max(1)),
        (None, Some(_)) => None,
        (None, None) => Some(scene.spp.max(1)),
    };
    // A share of the render takes its part of every pixel's sample indices; a time-limited share,
    // whose sample count is open, streams of its own.
    let (share_first, target, seed) = match target {
        Some(t) => {
            let r = options.share.range(t as u64);
            (r.start as u32, Some((r.end - r.start) as u32), options.seed)
        }
        None => (0, None, options.share.stream_seed(options.seed)),
    };
    let progress = make_progress(options, target, width * height);
    let mut stats = RenderStats::default();
    let invalid = AtomicU64::new(0);
    let rays = AtomicU64::new(0);
    let shadow_rays = AtomicU64::new(0);
    let mut done_spp: u32 = 0;
    let mut pass_size: u32 = 1;
    let mut snapshot_clock = SnapshotClock::new(options);

    loop {
        if let Some(t) = target {
            if done_spp >= t {
                break;
            }
            pass_size = pass_size.min(t - done_spp);
        }
        pass_size = pass_size.min(max_pass);
        if cancel.load(Ordering::Relaxed) {
            stats.interrupted = true;
            break;
        }
        if let Some(limit) = options.time_limit {
            if start.elapsed() >= limit {
                break;
            }
        }
        let pass_start = Instant::now();
        let pass_first = done_spp;
        let first_sample = options.first_sample.saturating_add(share_first).saturating_add(done_spp);
        let results: Vec<Option<TileResult>> = tiles
            .par_iter()
            .map(|tile| {
                if cancel.load(Ordering::Relaxed) {
                    return None;
                }
                let r = render_tile(scene, integrator, seed, tile, first_sample, pass_size, width);
                invalid.fetch_add(r.invalid, Ordering::Relaxed);
                rays.fetch_add(r.counters.rays, Ordering::Relaxed);
                shadow_rays.fetch_add(r.counters.shadow_rays, Ordering::Relaxed);
                if let Some(pb) = &progress {
                    if target.is_some() {
                        pb.inc((tile.w * tile.h) as u64 * pass_size as u64);
                    }
                }
                Some(r)
            })
            .collect();
        let complete = results.iter().all(Option::is_some);
        // A partial pass is dropped: with splats the light paths of the missing tiles would be missing
        // from every pixel's splat sum, and without, its pixels would hold samples past `min_spp`
        // that a resumed render (`first_sample = min_spp`) takes again. Every pixel has exactly
        // `min_spp` samples, which merging parts and checkpoints relies on; a pass is about half a
        // second of work.
        if complete {
            for (tile, r) in tiles.iter().zip(results) {
                let Some(r) = r else { continue };
                film.add_tile((tile.x, tile.y, tile.w, tile.h), &r.sums, &r.squares, pass_size);
                for &(layer, x, y, v) in &r.layer_values {
                    film.add_layer_sample(layer, x, y, v);
                }
                for splat in &r.splats {
                    film.add_splat(splat);
                }
                stats.samples += r.added;
            }
        }
        if !complete {
            stats.interrupted = true;
            break;
        }
        done_spp += pass_size;
        stats.passes += 1;
        let wants_state = snapshot_clock.wants_state();
        snapshot_clock.poll(start.elapsed(), || {
            film.splat_scale = 1.0 / done_spp as f64;
            Snapshot {
                elapsed: start.elapsed(),
                image: film.to_image(),
                samples: stats.samples,
                spp: done_spp,
                extra: Vec::new(),
                state: wants_state
                    .then(|| RenderState::new(film.clone(), Work::Pixels { spp: done_spp as u64 })),
            }
        });
        if let (Some(pb), None, Some(limit)) = (&progress, target, options.time_limit) {
            pb.set_position(start.elapsed().as_millis().min(limit.as_millis()) as u64);
            pb.set_message(format!("{done_spp} spp"));
        }
        // Aim for passes of about half a second so progress, time limits and Ctrl-C stay responsive.
        let pass_time = pass_start.elapsed().as_secs_f64().max(1e-4);
        let grow = (0.5 / (pass_time / pass_size as f64)).floor() as u32;
        pass_size = grow.clamp(1, 64).max(1);
        if let Some(limit) = options.time_limit {
            let remaining = limit.saturating_sub(start.elapsed()).as_secs_f64();
            let per_sample = pass_time / (done_spp - pass_first).max(1) as f64;
            let affordable = (remaining / per_sample).floor() as u32;
            if affordable == 0 {
                break;
            }
            pass_size = pass_size.min(affordable);
        }
        // End the next pass close to the next snapshot time rather than up to half a second later.
        if let Some(next) = snapshot_clock.next_time() {
            let until = next.saturating_sub(start.elapsed()).as_secs_f64();
            let per_sample = pass_time / (done_spp - pass_first).max(1) as f64;
            pass_size = pass_size.min(((until / per_sample).ceil() as u32).max(1));
        }
    }
    if let Some(pb) = progress {
        pb.finish_and_clear();
    }
    stats.min_spp = done_spp;
    // One light path per camera sample: each pixel's splat sum estimates its value times spp.
    film.splat_scale = if done_spp > 0 { 1.0 / done_spp as f64 } else { 0.0 };
    stats.invalid_samples = invalid.load(Ordering::Relaxed);
    stats.rays = rays.load(Ordering::Relaxed);
    stats.shadow_rays = shadow_rays.load(Ordering::Relaxed);
    stats.elapsed = start.elapsed();
    (film, stats)
}

#[derive(Clone, Copy, Debug)]
struct Tile {
    x: usize,
    y: usize,
    w: usize,
    h: usize,
}

fn tile_grid(width: usize, height: usize) -> Vec<Tile> {
    let mut tiles = Vec::new();
    for y in (0..height).step_by(TILE) {
        for x in (0..width).step_by(TILE) {
            tiles.push(Tile { x, y, w: TILE.min(width - x), h: TILE.min(height - y) });
        }
    }
    tiles
}

struct TileResult {
    /// Per-pixel sums of this pass, in f64 so long renders do not lose small contributions.
    sums: Vec<[f64; 3]>,
    squares: Vec<[f64; 3]>,
    added: u64,
    invalid: u64,
    counters: SampleCounters,
    splats: Vec<Splat>,
    /// (layer, x, y, value) at the sample's own pixel.
    layer_values: Vec<(u16, usize, usize, Spectrum)>,
}

fn render_tile(
    scene: &Scene,
    integrator: &dyn PixelIntegrator,
    seed: u64,
    tile: &Tile,
    first_sample: u32,
    count: u32,
    width: usize,
) -> TileResult {
    let mut sums = vec![[0.0f64; 3]; tile.w * tile.h];
    let mut squares = vec![[0.0f64; 3]; tile.w * tile.h];
    let mut out = SampleOutput::default();
    let mut splats = Vec::new();
    let mut layer_values = Vec::new();
    let signed_layers = integrator.signed_layers();
    let (mut added, mut invalid) = (0u64, 0u64);
    for py in 0..tile.h {
        for px in 0..tile.w {
            let (x, y) = (tile.x + px, tile.y + py);
            let pixel_index = (y * width + x) as u64;
            let acc = &mut sums[py * tile.w + px];
            let acc2 = &mut squares[py * tile.w + px];
            for s in first_sample..first_sample + count {
                let mut sampler = Sampler::new(seed, pixel_index, s as u64);
                let pos = film_position(scene, x, y, &mut sampler);
                let ray = scene.camera.generate_ray(pos);
                out.splats.clear();
                out.layer_values.clear();
                let l: Spectrum = integrator.li(scene, &ray, &mut sampler, &mut out);
                let valid = |v: Spectrum| v.is_finite() && v.min_element() >= 0.0;
                // A sample's estimates are kept or dropped together: its strategies' MIS weights assume all of them.
                let layer_valid = |v: Spectrum| if signed_layers { v.is_finite() } else { valid(v) };
                let all_valid = valid(l)
                    && out.splats.iter().all(|s| valid(s.value))
                    && out.layer_values.iter().all(|&(_, v)| layer_valid(v));
                if all_valid {
                    splats.extend_from_slice(&out.splats);
                    layer_values.extend(out.layer_values.iter().map(|&(layer, v)| (layer, x, y, v)));
                    for (c, v) in [l.x, l.y, l.z].into_iter().enumerate() {
                        acc[c] += v as f64;
                        acc2[c] += v as f64 * v as f64;
                    }
                } else {
                    // Counted and dropped; the pixel's sample count still advances, which keeps the
                    // estimator consistent (a zero sample) instead of biasing it upwards.
                    invalid += 1;
                }
                added += 1;
            }
        }
    }
    TileResult { sums, squares, added, invalid, counters: out.counters, splats, layer_values }
}

/// A film position for pixel (x, y) drawn from the reconstruction filter around the pixel centre,
/// truncated to the image: Mitsuba only places samples inside the film, so its border pixels see a
/// filter cut at the edge, and rejection reproduces exactly that truncated distribution.
fn film_position(scene: &Scene, x: usize, y: usize, sampler: &mut Sampler) -> glam::Vec2 {
    use glam::Vec2;
    let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
    let size = Vec2::new(scene.film.width as f32, scene.film.height as f32);
    let mut pos = centre;
    for _ in 0..32 {
        pos = centre + scene.film.rfilter.sample(sampler.next_2d());
        if pos.x >= 0.0 && pos.y >= 0.0 && pos.x < size.x && pos.y < size.y {
            return pos;
        }
    }
    // Practically unreachable (the pixel centre itself is inside): fall back to a clamped position.
    pos.clamp(Vec2::ZERO, size - Vec2::splat(1e-3))
}

fn make_progress(
    options: &RenderOptions,
    target: Option<u32>,
    pixels: usize,
) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    if !options.progress || !std::io::stderr().is_terminal() {
        return None;
    }
    let pb = match (target, options.time_limit) {
        (Some(t), _) => {
            let pb = indicatif::ProgressBar::new(t as u64 * pixels as u64);
            pb.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {wide_bar} {percent}% {per_sec} ETA {eta}",
                )
                .ok()?,
            );
            pb
        }
        (None, Some(limit)) => {
            let pb = indicatif::ProgressBar::new(limit.as_millis() as u64);
            pb.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {wide_bar} {msg} ETA {eta}",
                )
                .ok()?,
            );
            pb
        }
        (None, None) => return None,
    };
    Some(pb)
}
