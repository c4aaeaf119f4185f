//! Path-space Metropolis light transport (Veach & Guibas 1997; Mitsuba's `mlt` and `memlt`): chains walk
//! over whole paths with a weighted mixture of mutations (`mutations`), started from paths of a BDPT
//! seeding pass drawn in proportion to their weighted contribution, which removes start-up bias.
//! MLT, MEMLT, HSLT and HSLT+MLT are this integrator with different mutation sets.

use super::chain::{Chain, MutationStats, TargetFunction, WeightedMutation};
use super::direct;
use super::driver::{self, ChainRunner, RunningChain};
use super::mutations::largestep::StrategyPmf;
use super::mutations::{self, MutationKind, MutationSettings};
use super::normalization;
use super::path_state::{PathContext, PathState};
use super::pssmlt::{acceptance_extra, sample_cdf, PssContext, Pssmlt};
use crate::integrators::{bdpt::Contribution, Bdpt};
use crate::render::{Film, Integrator, RenderOptions, RenderOutput, RenderStats, SampleCounters, Work};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::luminance;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

const CHAIN_STREAM: u64 = 0x9A7C;
/// Seed samples evaluated per parallel work item.
const SEED_CHUNK: usize = 4096;
/// Draws of a starting path before a chain gives up (only paths BDPT found but whose f is zero in our
/// evaluation are redrawn, which should not happen).
const START_ATTEMPTS: usize = 16;

/// Path-space MLT parameters (CLI: `--mutations`, `--seed-paths`, `--chains`, `--lambda`).
#[derive(Clone, Debug, PartialEq)]
pub struct MltSettings {
    /// Independent BDPT samples of the seeding pass; `None` = `default_seed_paths`, and with a time
    /// limit as many more as fit in `seed_share` of it.
    pub seed_paths: Option<usize>,
    /// The fraction of a time-limited render the seeding pass runs for when `seed_paths` is `None`
    /// (CLI: `--seed-share`; default `SEED_TIME_SHARE`).
    pub seed_share: f64,
    pub chains: usize,
    /// Mutations of a chain between its restarts from fresh seed draws (CLI: `--restart-every`;
    /// 0 never restarts; default `DEFAULT_RESTART_EVERY`).
    pub restart_every: u64,
    /// The mixture: each mutation with its selection weight.
    pub mutations: Vec<(MutationKind, f64)>,
    pub target: TargetFunction,
    /// Parameters of the individual mutations.
    pub mutation: MutationSettings,
    /// The separate direct-illumination pass (`metropolis::direct`); `Off` lets the chains render
    /// direct illumination too.
    pub direct: direct::DirectPass,
}

impl MltSettings {
    /// The defaults of a technique: Veach's MLT set, MEMLT (Veach's set plus the manifold
    /// perturbation), HSLT (half-vector mutation with the bidirectional mutation) or HSLT+MLT.
    pub fn for_technique(mutations: Vec<(MutationKind, f64)>) -> MltSettings {
        MltSettings {
            seed_paths: None,
            seed_share: SEED_TIME_SHARE,
            chains: DEFAULT_PATH_CHAINS,
            restart_every: DEFAULT_RESTART_EVERY,
            mutations,
            target: TargetFunction::Luminance,
            mutation: MutationSettings::default(),
            direct: direct::DirectPass::Off,
        }
    }
}

/// Chains of a path-space technique unless `--chains` says otherwise (and no more than there are
/// mutations). Each chain carries 1/chains of the image's energy wherever it wanders, and chains that
/// mix slowly between families of paths keep most of it near where they started, so the chain starts
/// are a sample of the image in their own right. On nested-glass (MEMLT, 48×36, 60 s, seeds 1–3) 4096
/// chains had half the 6×6-block relative MSE of 1024 (2.0e-3 against 4.4e-3 on average); on rings
/// and jewelry (hslt, 64×48, 20 s) they did as well as 1024, and 16 384 did no better on nested-glass
/// and 40% worse on rings (docs/mlt.md). Starting one costs a seed draw (`seed_group` BDPT samples).
pub const DEFAULT_PATH_CHAINS: usize = 4096;

/// Mutations a path-space chain runs before it restarts from a fresh seed draw, unless
/// `--restart-every` says otherwise (`RestartingChain`). A chain caught on a rare bright path keeps
/// its energy there only until its next restart, and each restart places the chains systematically
/// again, so the seeds' weights are stratified by chains × restarts starts instead of by chains. A
/// restart replays a seed group (up to 16 BDPT samples): every 256 mutations that cost jewelry 10% of
/// its mutations. Relative MSE at 60 s, seeds 1–3 (docs/mlt.md), never / 256 / 1024 / 4096:
/// jewelry `hslt+mlt` (about 12 000 mutations per chain) mean 1.72 / 1.30 / 1.36 / 1.22e-3;
/// nested-glass `memlt` 6×6 blocks 2.47 / 1.80 / 1.76 / 1.78e-3, whole image 3.81 / 3.23 / 3.02 /
/// 3.60e-2: 1024 is the best on nested-glass and within the seeds' scatter of the best on jewelry.
pub const DEFAULT_RESTART_EVERY: u64 = 1024;

/// Seed paths of a path-space technique with a fixed amount of work, unless `--seed-paths` says
/// otherwise: one per 16 mutations and at least sixteen per pixel and 65 536, at most 2^24 (16 MiB of
/// seeding state, `SEED_GROUP`). Path-space chains mix slowly between families of paths, so the seeding
/// pass's estimate of how much light each family carries is largely what the image keeps: its
/// fireflies become the chains' blotches (`PathSeeds::largest`). On nested-glass (MEMLT, 48×36, 60 s)
/// 2^16 seed paths put 4.3% of b on one path and 44 of 1024 chains on it, and the 6×6-block relative
/// MSE was 6.9e-2; 2^20 gave 8.5e-3 for 2.5 s of seeding (docs/rough-glass.md).
/// `mutations` is `u64::MAX` for a render with only a time limit, which takes the minimum and then
/// seeds for `SEED_TIME_SHARE` of its time instead.
pub fn default_seed_paths(pixels: usize, mutations: u64) -> usize {
    let per_mutations = if mutations == u64::MAX { 0 } else { (mutations / 16).min(1 << 24) as usize };
    (16 * pixels).max(per_mutations).clamp(65_536, 1 << 24)
}

/// Share of a time-limited render (`--time`, no `--seed-paths`) that the seeding pass runs for, after
/// the `default_seed_paths` minimum: a seed sample costs about as much as a few mutations, and the
/// chains cannot make up for a thin seeding pass (`default_seed_paths`).
pub const SEED_TIME_SHARE: f64 = 0.2;

/// Seed samples per extension of a time-limited seeding pass, at least.
const SEED_EXTENSION_MIN: usize = 2 * SEED_CHUNK;

/// Most seed samples a time-limited pass extends to: 2^28 keep 256 MiB of group sums (`SEED_GROUP`),
/// about ten minutes of seeding on two cores.
const SEED_PATHS_MAX: usize = 1 << 28;

pub struct PathMlt {
    pub name: &'static str,
    pub bdpt: Bdpt,
    pub settings: MltSettings,
}

/// Seed samples per group in a long pass: the seeding pass keeps one running sum per group, not per
/// strategy, and a draw replays the samples of its group to find the strategy (at most this many BDPT
/// samples). Memory is then about one byte per seed sample, so the pass can be long
/// (`SEED_TIME_SHARE`).
const SEED_GROUP: usize = 16;

/// Passes of at most this many samples keep a sum per sample (16 MiB at most), so a chain's start
/// replays one sample: with 4096 chains and a pass of 65 536 samples, replaying groups of 16 cost
/// as much as the pass itself.
const UNGROUPED_SEED_PATHS: usize = 1 << 20;

/// Samples per group of a pass of `n` samples (`SEED_CHUNK` is a multiple of both).
fn seed_group(n: usize) -> usize {
    if n <= UNGROUPED_SEED_PATHS {
        1
    } else {
        SEED_GROUP
    }
}

/// A seed strategy counted by the pass: its luminance if it can start a chain (positive and finite),
/// or why not. Pass and replay must classify alike, so both use this.
fn candidate_luminance(c: &Contribution) -> Result<f64, ()> {
    let y = luminance(c.value) as f64;
    if !(y.is_finite() && c.value.min_element() >= 0.0) {
        Err(())
    } else {
        Ok(y)
    }
}

/// The seeding pass: independent BDPT samples (replayable by index) and the luminance of each of their
/// weighted strategies. b, the mean of the per-sample sums, is the integral of luminance(f) over path
/// space: the normalisation of the chains' image.
pub struct PathSeeds {
    /// First sample index of each group and the running sum of luminance up to the group's end.
    group_first: Vec<usize>,
    cdf: Vec<f64>,
    /// One past the last sample index of the pass.
    end: usize,
    candidates: usize,
    pub samples: usize,
    pub b: f64,
    /// Σ over groups of (the group's luminance sum)², for the variance of b.
    group_square_sum: f64,
    /// Σ luminance of the weighted strategies by edge count k (= vertices − 1) and light-side vertex
    /// count s (`by_strategy[k][s]`): which lengths carry the light and which of BDPT's strategies make
    /// them well, which the large step proposes from (`largestep::StrategyPmf`).
    pub by_strategy: Vec<Vec<f64>>,
    /// The largest luminance one strategy of one sample carried. Chains start on paths in proportion
    /// to these, so a seed path holding a share q of the sum starts about q · chains of them, and where
    /// the mutations cannot carry them away (near-specular paths, `docs/rough-glass.md`) the image keeps
    /// that much energy there: the seeding pass's fireflies become the chains' blotches.
    pub largest: f64,
    pub rays: SampleCounters,
    pub invalid: u64,
}

/// What one parallel chunk of the seeding pass found.
#[derive(Default)]
struct SeedChunk {
    /// (first sample, Σ luminance) per group.
    groups: Vec<(usize, f64)>,
    by_strategy: Vec<Vec<f64>>,
    candidates: usize,
    largest: f64,
    rays: SampleCounters,
    invalid: u64,
}

fn add_to_histogram(histogram: &mut Vec<Vec<f64>>, edges: usize, split: usize, y: f64) {
    if histogram.len() <= edges {
        histogram.resize(edges + 1, Vec::new());
    }
    let splits = &mut histogram[edges];
    if splits.len() <= split {
        splits.resize(split + 1, 0.0);
    }
    splits[split] += y;
}

impl PathSeeds {
    pub fn run(scene: &Scene, bdpt: &Bdpt, seed: u64, n: usize, cancel: &AtomicBool) -> PathSeeds {
        PathSeeds::run_range(scene, bdpt, seed, 0..n, cancel)
    }

    /// Runs the seed samples with indices `indices` (a share of a render takes its share of them).
    pub fn run_range(
        scene: &Scene,
        bdpt: &Bdpt,
        seed: u64,
        indices: std::ops::Range<usize>,
        cancel: &AtomicBool,
    ) -> PathSeeds {
        let group = seed_group(indices.len());
        PathSeeds::run_grouped(scene, bdpt, seed, indices, group, cancel)
    }

    /// `run_range` with one running sum per `group` samples (a divisor of `SEED_CHUNK`); the draws
    /// are the same for every grouping, only their cost and the memory differ.
    pub fn run_grouped(
        scene: &Scene,
        bdpt: &Bdpt,
        seed: u64,
        indices: std::ops::Range<usize>,
        group: usize,
        cancel: &AtomicBool,
    ) -> PathSeeds {
        assert!(group > 0 && SEED_CHUNK % group == 0, "seed groups must tile the chunks");
        let (first, n) = (indices.start, indices.len());
        let chunks: Vec<SeedChunk> = (0..n.div_ceil(SEED_CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let mut out = SeedChunk::default();
                if cancel.load(Ordering::Relaxed) {
                    return out;
                }
                let chunk_end = first + ((chunk + 1) * SEED_CHUNK).min(n);
                for i in first + chunk * SEED_CHUNK..chunk_end {
                    if (i - first) % group == 0 {
                        out.groups.push((i, 0.0));
                    }
                    let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, i));
                    let _ = ctx.evaluate();
                    out.rays += ctx.counters;
                    let group = &mut out.groups.last_mut().expect("a group per sample").1;
                    for c in ctx.contributions() {
                        match candidate_luminance(c) {
                            Err(()) => out.invalid += 1,
                            Ok(y) if y > 0.0 => {
                                *group += y;
                                out.candidates += 1;
                                out.largest = out.largest.max(y);
                                // `Contribution::path` adds the environment vertex an s = 0 path escaped to.
                                let env = usize::from(c.s == 0 && c.endpoint.is_some());
                                let edges = (c.s + c.t + env).saturating_sub(1);
                                // The large step reaches an environment by sampling it (s = 1), never
                                // by an eye walk hitting it.
                                add_to_histogram(&mut out.by_strategy, edges, c.s.max(env), y);
                            }
                            Ok(_) => {}
                        }
                    }
                }
                out
            })
            .collect();
        let mut seeds = PathSeeds {
            group_first: Vec::new(),
            cdf: Vec::new(),
            end: first + n,
            candidates: 0,
            samples: n,
            b: 0.0,
            group_square_sum: 0.0,
            by_strategy: Vec::new(),
            largest: 0.0,
            rays: SampleCounters::default(),
            invalid: 0,
        };
        let mut sum = 0.0;
        for chunk in chunks {
            seeds.rays += chunk.rays;
            seeds.invalid += chunk.invalid;
            seeds.candidates += chunk.candidates;
            seeds.largest = seeds.largest.max(chunk.largest);
            for (edges, splits) in chunk.by_strategy.iter().enumerate() {
                for (split, &y) in splits.iter().enumerate() {
                    add_to_histogram(&mut seeds.by_strategy, edges, split, y);
                }
            }
            for (group_first, y) in chunk.groups {
                sum += y;
                seeds.group_square_sum += y * y;
                seeds.group_first.push(group_first);
                seeds.cdf.push(sum);
            }
        }
        seeds.b = if n > 0 { sum / n as f64 } else { 0.0 };
        seeds
    }

    /// Adds the pass `more`, whose samples must directly follow this one's (a time-limited pass runs
    /// in parts, `extend_seeds`).
    pub fn append(&mut self, more: PathSeeds) {
        assert!(more.group_first.first().is_none_or(|&f| f == self.end), "seed passes must be contiguous");
        let sum = self.cdf.last().copied().unwrap_or(0.0);
        self.group_first.extend(more.group_first);
        self.cdf.extend(more.cdf.iter().map(|c| c + sum));
        self.end += more.samples;
        self.candidates += more.candidates;
        self.samples += more.samples;
        self.group_square_sum += more.group_square_sum;
        self.b = if self.samples > 0 {
            self.cdf.last().copied().unwrap_or(0.0) / self.samples as f64
        } else {
            0.0
        };
        for (edges, splits) in more.by_strategy.iter().enumerate() {
            for (split, &y) in splits.iter().enumerate() {
                add_to_histogram(&mut self.by_strategy, edges, split, y);
            }
        }
        self.largest = self.largest.max(more.largest);
        self.rays += more.rays;
        self.invalid += more.invalid;
    }

    /// The standard error of b, from the spread of the group sums: a group of m samples has m times
    /// a sample's variance σ² about m · b, so Σ G² − b² Σ m² (`m2`) estimates n σ² (0 from
    /// fewer than two samples).
    pub fn b_standard_error(&self) -> f64 {
        let ends = self.group_first.iter().skip(1).copied().chain(std::iter::once(self.end));
        let m2: f64 = self.group_first.iter().zip(ends).map(|(&a, b)| ((b - a) as f64).powi(2)).sum();
        let n = self.samples as f64;
        let variance = ((self.group_square_sum - self.b * self.b * m2) / n).max(0.0);
        (variance / n).sqrt()
    }

    /// The share of b's sum on the single heaviest seed path (0 when there is none).
    pub fn largest_share(&self) -> f64 {
        let total = self.b * self.samples as f64;
        if total > 0.0 {
            self.largest / total
        } else {
            0.0
        }
    }

    /// Number of strategies with a positive contribution.
    pub fn candidates(&self) -> usize {
        self.candidates
    }

    /// A path drawn in proportion to its weighted contribution (replayed from its seed sample): the
    /// group holding u · Σ, then the strategy within it where the running sum passes that point.
    pub fn draw(&self, scene: &Scene, bdpt: &Bdpt, seed: u64, u: f64) -> Option<PathState> {
        let g = sample_cdf(&self.cdf, u)?;
        let before = if g > 0 { self.cdf[g - 1] } else { 0.0 };
        let mut rest = u * self.cdf.last()? - before;
        // Groups tile the pass: each ends where the next begins.
        let group_end = self.group_first.get(g + 1).copied().unwrap_or(self.end);
        // The last positive strategy of the group, should rounding leave `rest` beyond the group's sum.
        let mut last = None;
        'samples: for i in self.group_first[g]..group_end {
            let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, i));
            let _ = ctx.evaluate();
            for (j, c) in ctx.contributions().iter().enumerate() {
                if let Ok(y) = candidate_luminance(c) {
                    if y > 0.0 {
                        last = Some((i, j));
                        rest -= y;
                        if rest < 0.0 {
                            break 'samples;
                        }
                    }
                }
            }
        }
        let (i, j) = last?;
        let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, i));
        let (_, sub) = ctx.evaluate_with_paths();
        let contribution = ctx.contributions().get(j)?;
        PathState::new(scene, contribution.path(&sub))
    }
}

/// Runs more seed samples after `seeds` until `budget` has passed since `started`, in batches sized by
/// the rate so far (so the pass ends close to its budget), then appends them.
fn extend_seeds(
    seeds: &mut PathSeeds,
    scene: &Scene,
    bdpt: &Bdpt,
    seed: u64,
    budget: std::time::Duration,
    started: Instant,
    cancel: &AtomicBool,
) {
    while !cancel.load(Ordering::Relaxed) {
        let elapsed = started.elapsed();
        let Some(left) = budget.checked_sub(elapsed) else { break };
        let rate = seeds.samples as f64 / elapsed.as_secs_f64().max(1e-6);
        let room = SEED_PATHS_MAX.saturating_sub(seeds.samples);
        let batch =
            (rate * left.as_secs_f64()).min(seeds.samples.max(SEED_EXTENSION_MIN).min(room) as f64) as usize;
        if batch < SEED_EXTENSION_MIN {
            break;
        }
        let first = seeds.end;
        let more = PathSeeds::run_range(scene, bdpt, seed, first..first + batch, cancel);
        if cancel.load(Ordering::Relaxed) {
            // An interrupted batch left samples out of its sums.
            break;
        }
        seeds.append(more);
    }
}

/// A path-space chain that restarts from a fresh seed draw every `every` of its mutations. Each
/// restart draws from the seeds in proportion to their weights, so the chain is in its stationary
/// distribution after it as from its first mutation, whatever state it left (restarts come at fixed
/// counts, never depending on the state): the estimate stays unbiased. What restarts change is how
/// long a chain that cannot leave a rare bright path keeps its energy there, and how finely the
/// starts (systematic over the render's chains at each restart, `driver::systematic_position`)
/// stratify the seeds' weights.
struct RestartingChain<'a> {
    runner: ChainRunner<PathState, PathContext<'a>>,
    seeds: &'a PathSeeds,
    seed: u64,
    /// This chain's index among the render's `count` chains.
    index: usize,
    count: usize,
    every: u64,
    /// Mutations since the last (re)start, restart points passed, and the restarts made at them (a
    /// draw whose path does not evaluate leaves the chain where it is).
    since_start: u64,
    rounds: u64,
    restarts: u64,
}

impl RunningChain for RestartingChain<'_> {
    fn advance(
        &mut self,
        max: u64,
        deadline: Option<Instant>,
        cancel: &AtomicBool,
        out: &mut Vec<crate::render::Splat>,
    ) -> u64 {
        let mut done = 0;
        while done < max {
            if self.since_start >= self.every {
                self.since_start = 0;
                self.rounds += 1;
                let offset_seed = self.seed ^ self.rounds.wrapping_mul(0x9E37_79B9_7F4A_7C15);
                let position = driver::systematic_position(offset_seed, CHAIN_STREAM, self.index, self.count);
                let ctx = &self.runner.ctx;
                if let Some(start) = self.seeds.draw(ctx.scene, ctx.bdpt, self.seed, position) {
                    if self.runner.chain.restart(start) {
                        self.restarts += 1;
                    }
                }
            }
            let n = (max - done).min(self.every - self.since_start);
            let ran = self.runner.advance(n, deadline, cancel, out);
            done += ran;
            self.since_start += ran;
            if ran < n {
                break;
            }
        }
        done
    }

    fn stats(&self) -> &[MutationStats] {
        self.runner.stats()
    }

    fn rays(&self) -> u64 {
        self.runner.rays()
    }

    fn shadow_rays(&self) -> u64 {
        self.runner.shadow_rays()
    }

    fn streaks(&self) -> super::chain::Streaks {
        self.runner.streaks()
    }

    fn restarts(&self) -> u64 {
        self.restarts
    }
}

impl PathMlt {
    /// With `settings.direct` enabled the chains and the seeding pass run on `bdpt` without its
    /// direct-lighting paths (`direct::chain_bdpt`), which the render estimates separately.
    pub fn new(name: &'static str, bdpt: Bdpt, settings: MltSettings) -> PathMlt {
        let large_step = settings.mutations.iter().any(|&(k, w)| k == MutationKind::LargeStep && w > 0.0);
        let settings = MltSettings { direct: settings.direct.for_path_space(large_step), ..settings };
        PathMlt { name, bdpt: direct::chain_bdpt(bdpt, settings.direct), settings }
    }

    fn build_mutations(
        &self,
        scene: &Scene,
        settings: &MutationSettings,
    ) -> Vec<WeightedMutation<PathState, PathContext<'_>>> {
        self.settings
            .mutations
            .iter()
            .filter(|(_, w)| *w > 0.0)
            .filter_map(|&(kind, weight)| {
                let mutation = mutations::make(kind, settings, scene)?;
                Some(WeightedMutation { mutation, weight })
            })
            .collect()
    }

    /// A chain on the seed path at `position` of the seeds' cumulative weights
    /// (`driver::systematic_position`), and how many of its draws failed: a draw whose path does not
    /// evaluate (f zero or out of range) is redrawn at a random position, which moves that path's
    /// share of b onto others, so the count goes into the metadata (it exposed f32 overflow on
    /// jewelry's diamond).
    fn start_chain<'a>(
        &'a self,
        scene: &'a Scene,
        seeds: &PathSeeds,
        settings: &MutationSettings,
        seed: u64,
        chain_index: usize,
        position: f64,
    ) -> (Option<ChainRunner<PathState, PathContext<'a>>>, usize) {
        let mut rng = Sampler::new(seed, chain_index as u64, CHAIN_STREAM);
        let target = self.settings.target;
        for attempt in 0..START_ATTEMPTS {
            let u = if attempt == 0 { position } else { rng.next_f64() };
            let Some(start) = seeds.draw(scene, &self.bdpt, seed, u) else { continue };
            if target.of(&start) > 0.0 {
                let mutations = self.build_mutations(scene, settings);
                if mutations.is_empty() {
                    return (None, attempt);
                }
                let mut chain = Chain::new(start, mutations, target, rng);
                if self.bdpt.min_path_vertices > 2 {
                    let min_vertices = self.bdpt.min_path_vertices;
                    chain = chain.with_support(Box::new(move |s: &PathState| s.len() >= min_vertices));
                }
                return (Some(ChainRunner { chain, ctx: PathContext::new(scene, &self.bdpt) }), attempt);
            }
        }
        (None, START_ATTEMPTS)
    }
}

impl Integrator for PathMlt {
    fn name(&self) -> &'static str {
        self.name
    }

    fn render(&self, scene: &Scene, options: &RenderOptions, cancel: &AtomicBool) -> RenderOutput {
        let start_time = Instant::now();
        let pixels = (scene.film.width * scene.film.height).max(1);
        let film = Film::with_filter(scene.film.width, scene.film.height, scene.film.rfilter);
        let mut stats = RenderStats::default();
        let mut metadata: Vec<(String, String)> = Vec::new();
        let mut film = film;
        let direct = self.settings.direct;
        direct::render_into(&mut film, scene, &self.bdpt, direct, options, cancel, &mut stats, &mut metadata);
        let seed = options.seed ^ (options.first_sample as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let total_mutations = driver::total_mutations(options, scene);
        let all_seeds =
            self.settings.seed_paths.unwrap_or_else(|| default_seed_paths(pixels, total_mutations)).max(1);
        let seed_range = options.share.range(all_seeds as u64);
        let seed_indices = seed_range.start as usize..seed_range.end as usize;
        let seeding_start = Instant::now();
        let mut seeds = PathSeeds::run_range(scene, &self.bdpt, seed, seed_indices, cancel);
        // A time-limited render seeds for its share of the time; a farm part keeps its share of the
        // indices (the parts' passes would overlap past them).
        let seeding_time = match (options.time_limit, self.settings.seed_paths, options.share.is_whole()) {
            (Some(limit), None, true) => Some(limit.mul_f64(self.settings.seed_share.clamp(0.0, 1.0))),
            _ => None,
        };
        if let Some(budget) = seeding_time {
            extend_seeds(&mut seeds, scene, &self.bdpt, seed, budget, seeding_start, cancel);
        }
        let n_seed = seeds.samples;
        stats.rays += seeds.rays.rays;
        stats.shadow_rays += seeds.rays.shadow_rays;
        stats.invalid_samples += seeds.invalid;
        let b = seeds.b;
        metadata.push(("hslt.mlt.seed_paths".into(), n_seed.to_string()));
        metadata.push(("hslt.mlt.seed_candidates".into(), seeds.candidates().to_string()));
        metadata.push(("hslt.mlt.normalization".into(), format!("{b:.6e}")));
        metadata.push(("hslt.mlt.seed_largest_share".into(), format!("{:.3e}", seeds.largest_share())));
        let mutation_names: Vec<String> =
            self.settings.mutations.iter().map(|(k, w)| format!("{}:{w}", k.name())).collect();
        metadata.push(("hslt.mlt.mutation_set".into(), mutation_names.join(",")));
        if self.settings.mutations.iter().any(|(k, _)| *k == MutationKind::HalfVector) {
            let direction = self.settings.mutation.halfvector.direction.name();
            metadata.push(("hslt.mlt.hslt.direction".into(), direction.into()));
            let chains = if self.settings.mutation.halfvector.sub_chains { "sub" } else { "whole" };
            metadata.push(("hslt.mlt.hslt.chains".into(), chains.into()));
        }
        if cancel.load(Ordering::Relaxed) || !(b > 0.0 && b.is_finite()) {
            stats.interrupted = cancel.load(Ordering::Relaxed);
            // An interrupted seeding pass left samples out of its sum, so it counts for nothing.
            let work = match stats.interrupted {
                true => Work::Chains { mutations: 0, b_sum: 0.0, b_samples: 0 },
                false => {
                    metadata
                        .push(("hslt.mlt.status".into(), driver::empty_seeding_status(n_seed, &self.bdpt)));
                    Work::Chains { mutations: 0, b_sum: b * n_seed as f64, b_samples: n_seed as u64 }
                }
            };
            film.splat_scale = 0.0;
            stats.elapsed = start_time.elapsed();
            return RenderOutput { film, stats, metadata, work };
        }
        let chain_range = driver::chain_range(options, self.settings.chains, total_mutations);
        let n_chains = chain_range.len();
        let chains_start = Instant::now();
        let mut mutation_settings = self.settings.mutation.clone();
        mutation_settings.large_step_strategies = StrategyPmf::from_histogram(&seeds.by_strategy, &self.bdpt);
        // Starting a million chains takes seconds and gigabytes: a cancel (Ctrl-C, --max-memory) stops it too.
        let first_chain = chain_range.start;
        let started: Vec<_> = chain_range
            .into_par_iter()
            .map(|c| match cancel.load(Ordering::Relaxed) {
                true => (None, 0),
                false => {
                    let position = driver::systematic_position(seed, CHAIN_STREAM, c - first_chain, n_chains);
                    self.start_chain(scene, &seeds, &mutation_settings, seed, c, position)
                }
            })
            .collect();
        if cancel.load(Ordering::Relaxed) {
            stats.interrupted = true;
            film.splat_scale = 0.0;
            stats.elapsed = start_time.elapsed();
            // The seeding pass is complete: its estimate of b counts, with no mutations.
            let work = Work::Chains { mutations: 0, b_sum: b * n_seed as f64, b_samples: n_seed as u64 };
            return RenderOutput { film, stats, metadata, work };
        }
        let redraws: usize = started.iter().map(|(_, r)| r).sum();
        metadata.push(("hslt.mlt.seed_redraws".into(), redraws.to_string()));
        let restart_every = self.settings.restart_every;
        let seeds_ref = &seeds;
        let mut chains: Vec<Box<dyn RunningChain + '_>> = started
            .into_iter()
            .enumerate()
            .filter_map(|(i, (c, _))| c.map(|c| (i, c)))
            .map(|(index, runner)| match restart_every {
                every @ 1.. => Box::new(RestartingChain {
                    runner,
                    seeds: seeds_ref,
                    seed,
                    index,
                    count: n_chains,
                    every,
                    since_start: 0,
                    rounds: 0,
                    restarts: 0,
                }) as Box<dyn RunningChain + '_>,
                _ => Box::new(runner) as Box<dyn RunningChain + '_>,
            })
            .collect();
        if chains.len() < n_chains {
            metadata.push((
                "hslt.mlt.warning".into(),
                format!("{} of {n_chains} chains found no starting path", n_chains - chains.len()),
            ));
        }
        let quotas = driver::quotas(total_mutations, chains.len());
        // b from the seeding pass alone (`normalization`): the large steps' estimate is heavy-tailed.
        let normalization = |_: &[MutationStats]| (b * n_seed as f64, n_seed as u64);
        let outcome = driver::drive(
            options,
            cancel,
            start_time,
            normalization,
            film,
            &mut chains,
            &quotas,
            acceptance_extra,
        );
        let (b_sum, b_samples) = normalization(&outcome.stats);
        metadata.push(("hslt.mlt.normalization_final".into(), format!("{:.6e}", b_sum / b_samples as f64)));
        metadata.extend(normalization::metadata(b, seeds.b_standard_error(), &outcome.stats));
        let mutation_stats: Vec<MutationStats> = outcome.stats;
        stats.rays += outcome.rays;
        stats.shadow_rays += outcome.shadow_rays;
        stats.interrupted |= outcome.interrupted;
        stats.samples = outcome.mutations;
        stats.min_spp = (outcome.mutations / pixels as u64).min(u32::MAX as u64) as u32;
        stats.passes = 1;
        stats.invalid_samples += mutation_stats.iter().map(|s| s.rejected_invalid).sum::<u64>();
        stats.elapsed = start_time.elapsed();
        metadata.push(("hslt.mlt.chains".into(), chains.len().to_string()));
        metadata.push(("hslt.mlt.restart_every".into(), restart_every.to_string()));
        metadata
            .push(("hslt.mlt.restarts".into(), chains.iter().map(|c| c.restarts()).sum::<u64>().to_string()));
        metadata.push(("hslt.mlt.mutations".into(), outcome.mutations.to_string()));
        metadata.extend(driver::mutation_metadata(&mutation_stats));
        metadata.extend(driver::streak_metadata(&outcome.streaks, outcome.mutations));
        metadata.push((
            "hslt.mlt.seconds_seeding".into(),
            format!("{:.3}", driver::seconds(start_time, chains_start)),
        ));
        RenderOutput { film: outcome.film, stats, metadata, work: outcome.work }
    }
}
