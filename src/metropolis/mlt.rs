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
use super::pssmlt::acceptance_extra;
use super::seeds::extend_seeds;
pub use super::seeds::PathSeeds;
use crate::integrators::Bdpt;
use crate::render::{Film, Integrator, RenderOptions, RenderOutput, RenderStats, Work};
use crate::sampling::Sampler;
use crate::scene::Scene;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

const CHAIN_STREAM: u64 = 0x9A7C;
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
/// chains cannot make up for a thin seeding pass (`default_seed_paths`). 0.4 rather than 0.2: at 60 s
/// it lowered jewelry's `hslt+mlt` error by 31% (64×48) and nested-glass MEMLT's 25-px block error
/// 2.5× at 256×192, where a fifth of the time left 67 seed paths per pixel, and left rings' unchanged
/// (docs/rough-glass.md, "At the measure").
pub const SEED_TIME_SHARE: f64 = 0.4;

pub struct PathMlt {
    pub name: &'static str,
    pub bdpt: Bdpt,
    pub settings: MltSettings,
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

    fn failed_restarts(&self) -> u64 {
        self.rounds - self.restarts
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
        let mut chains: Vec<Box<dyn RunningChain + '_>> = started
            .into_iter()
            .enumerate()
            .filter_map(|(i, (c, _))| c.map(|c| (i, c)))
            .map(|(index, runner)| match restart_every {
                every @ 1.. => Box::new(RestartingChain {
                    runner,
                    seeds: &seeds,
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
        let failed_restarts: u64 = chains.iter().map(|c| c.failed_restarts()).sum();
        metadata.push(("hslt.mlt.restarts_failed".into(), failed_restarts.to_string()));
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
