//! Path-space Metropolis light transport (Veach & Guibas 1997; Mitsuba's `mlt` and `memlt`): chains walk
//! over whole paths with a weighted mixture of mutations (`mutations`), started from paths of a BDPT
//! seeding pass drawn in proportion to their weighted contribution, which removes start-up bias.
//! MLT, MEMLT, HSLT and HSLT+MLT are this integrator with different mutation sets.

use super::chain::{Chain, MutationStats, TargetFunction, WeightedMutation};
use super::direct;
use super::driver::{self, ChainRunner, RunningChain};
use super::mutations::largestep::{self, StrategyPmf};
use super::mutations::{self, MutationKind, MutationSettings};
use super::path_state::{PathContext, PathState};
use super::pssmlt::{acceptance_extra, sample_cdf, PssContext, Pssmlt};
use crate::integrators::Bdpt;
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
    /// Independent BDPT samples of the seeding pass; `None` = `default_seed_paths`.
    pub seed_paths: Option<usize>,
    pub chains: usize,
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
            chains: DEFAULT_PATH_CHAINS,
            mutations,
            target: TargetFunction::Luminance,
            mutation: MutationSettings::default(),
            direct: direct::DirectPass::Off,
        }
    }
}

/// Chains of a path-space technique unless `--chains` says otherwise. Each chain carries 1/chains of
/// the image's energy wherever it wanders, so few chains leave bright blotches where one lingers: on
/// the jewelry scene (128×96, 30-60 s) 1024 chains have 2-3 times lower relative MSE than 64. Unlike
/// PSSMLT's, these chains have no large steps to spread them out.
pub const DEFAULT_PATH_CHAINS: usize = 1024;

/// Seed paths of a path-space technique unless `--seed-paths` says otherwise: sixteen per pixel,
/// between 65 536 and 2^20. Path-space chains have no independent proposals to refine b with, so the
/// seeding pass alone sets the image's scale; on the jewelry scene 49 152 seed paths left it 4% high,
/// 10^6 within 1%, at about a second of BDPT time.
pub fn default_seed_paths(pixels: usize) -> usize {
    (16 * pixels).clamp(65_536, 1 << 20)
}

pub struct PathMlt {
    pub name: &'static str,
    pub bdpt: Bdpt,
    pub settings: MltSettings,
}

/// One seed-pass strategy that can start a chain: its sample, its index among the sample's
/// contributions, and the running sum of luminance up to and including it.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    sample: usize,
    contribution: usize,
}

/// The seeding pass: independent BDPT samples (replayable by index) and the luminance of each of their
/// weighted strategies. b, the mean of the per-sample sums, is the integral of luminance(f) over path
/// space: the normalisation of the chains' image.
pub struct PathSeeds {
    candidates: Vec<Candidate>,
    cdf: Vec<f64>,
    pub samples: usize,
    pub b: f64,
    /// Σ luminance of the weighted strategies by edge count k (= vertices − 1) and light-side vertex
    /// count s (`by_strategy[k][s]`): which lengths carry the light and which of BDPT's strategies make
    /// them well, which the large step proposes from (`largestep::StrategyPmf`).
    pub by_strategy: Vec<Vec<f64>>,
    pub rays: SampleCounters,
    pub invalid: u64,
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
        type Chunk = (Vec<(Candidate, f64, (usize, usize))>, SampleCounters, u64, f64);
        let (first, n) = (indices.start, indices.len());
        let chunks: Vec<Chunk> = (0..n.div_ceil(SEED_CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let mut out: Chunk = (Vec::new(), SampleCounters::default(), 0, 0.0);
                if cancel.load(Ordering::Relaxed) {
                    return out;
                }
                for i in first + chunk * SEED_CHUNK..first + ((chunk + 1) * SEED_CHUNK).min(n) {
                    let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, i));
                    let _ = ctx.evaluate();
                    out.1 += ctx.counters;
                    for (j, c) in ctx.contributions().iter().enumerate() {
                        let y = luminance(c.value) as f64;
                        if !(y.is_finite() && c.value.min_element() >= 0.0) {
                            out.2 += 1;
                        } else if y > 0.0 {
                            out.3 += y;
                            // `Contribution::path` adds the environment vertex an s = 0 path escaped to.
                            let env = usize::from(c.s == 0 && c.endpoint.is_some());
                            let edges = (c.s + c.t + env).saturating_sub(1);
                            // The large step reaches an environment by sampling it (s = 1), never by
                            // an eye walk hitting it.
                            let split = c.s.max(env);
                            out.0.push((Candidate { sample: i, contribution: j }, y, (edges, split)));
                        }
                    }
                }
                out
            })
            .collect();
        let mut seeds = PathSeeds {
            candidates: Vec::new(),
            cdf: Vec::new(),
            samples: n,
            b: 0.0,
            by_strategy: Vec::new(),
            rays: SampleCounters::default(),
            invalid: 0,
        };
        let mut sum = 0.0;
        for (candidates, rays, invalid, _) in chunks {
            seeds.rays += rays;
            seeds.invalid += invalid;
            for (c, y, (edges, split)) in candidates {
                sum += y;
                if seeds.by_strategy.len() <= edges {
                    seeds.by_strategy.resize(edges + 1, Vec::new());
                }
                let splits = &mut seeds.by_strategy[edges];
                if splits.len() <= split {
                    splits.resize(split + 1, 0.0);
                }
                splits[split] += y;
                seeds.candidates.push(c);
                seeds.cdf.push(sum);
            }
        }
        seeds.b = if n > 0 { sum / n as f64 } else { 0.0 };
        seeds
    }

    /// Number of strategies with a positive contribution.
    pub fn candidates(&self) -> usize {
        self.candidates.len()
    }

    /// A path drawn in proportion to its weighted contribution (replayed from its seed sample).
    pub fn draw(&self, scene: &Scene, bdpt: &Bdpt, seed: u64, u: f64) -> Option<PathState> {
        let c = self.candidates[sample_cdf(&self.cdf, u)?];
        let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, c.sample));
        let (_, sub) = ctx.evaluate_with_paths();
        let contribution = ctx.contributions().get(c.contribution)?;
        PathState::new(scene, contribution.path(&sub))
    }
}

impl PathMlt {
    /// With `settings.direct` enabled the chains and the seeding pass run on `bdpt` without its
    /// direct-lighting paths (`direct::chain_bdpt`), which the render estimates separately.
    pub fn new(name: &'static str, bdpt: Bdpt, settings: MltSettings) -> PathMlt {
        let refines_b = settings.mutations.iter().any(|&(k, w)| k == MutationKind::LargeStep && w > 0.0);
        let settings = MltSettings { direct: settings.direct.for_path_space(refines_b), ..settings };
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

    /// A chain on a drawn seed path, and how many of its draws failed: a draw whose path does not
    /// evaluate (f zero or out of range) is redrawn, which moves that path's share of b onto
    /// others, so the count goes into the metadata (it exposed f32 overflow on jewelry's diamond).
    fn start_chain<'a>(
        &'a self,
        scene: &'a Scene,
        seeds: &PathSeeds,
        settings: &MutationSettings,
        seed: u64,
        chain_index: usize,
    ) -> (Option<ChainRunner<PathState, PathContext<'a>>>, usize) {
        let mut rng = Sampler::new(seed, chain_index as u64, CHAIN_STREAM);
        let target = self.settings.target;
        for attempt in 0..START_ATTEMPTS {
            let Some(start) = seeds.draw(scene, &self.bdpt, seed, rng.next_f64()) else { continue };
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
        let all_seeds = self.settings.seed_paths.unwrap_or_else(|| default_seed_paths(pixels)).max(1);
        let seed_range = options.share.range(all_seeds as u64);
        let n_seed = (seed_range.end - seed_range.start) as usize;
        let seed_indices = seed_range.start as usize..seed_range.end as usize;
        let seeds = PathSeeds::run_range(scene, &self.bdpt, seed, seed_indices, cancel);
        stats.rays += seeds.rays.rays;
        stats.shadow_rays += seeds.rays.shadow_rays;
        stats.invalid_samples += seeds.invalid;
        let b = seeds.b;
        metadata.push(("hslt.mlt.seed_paths".into(), n_seed.to_string()));
        metadata.push(("hslt.mlt.seed_candidates".into(), seeds.candidates().to_string()));
        metadata.push(("hslt.mlt.normalization".into(), format!("{b:.6e}")));
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
        let total_mutations = driver::total_mutations(options, scene);
        let chain_range = driver::chain_range(options, self.settings.chains, total_mutations);
        let n_chains = chain_range.len();
        let chains_start = Instant::now();
        let mut mutation_settings = self.settings.mutation.clone();
        mutation_settings.large_step_strategies = StrategyPmf::from_histogram(&seeds.by_strategy, &self.bdpt);
        // Starting a million chains takes seconds and gigabytes: a cancel (Ctrl-C, --max-memory) stops it too.
        let started: Vec<_> = chain_range
            .into_par_iter()
            .map(|c| match cancel.load(Ordering::Relaxed) {
                true => (None, 0),
                false => self.start_chain(scene, &seeds, &mutation_settings, seed, c),
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
        let mut chains: Vec<Box<dyn RunningChain + '_>> = started
            .into_iter()
            .filter_map(|(c, _)| c)
            .map(|c| Box::new(c) as Box<dyn RunningChain + '_>)
            .collect();
        if chains.len() < n_chains {
            metadata.push((
                "hslt.mlt.warning".into(),
                format!("{} of {n_chains} chains found no starting path", n_chains - chains.len()),
            ));
        }
        let quotas = driver::quotas(total_mutations, chains.len());
        // b from the seeding pass and every large step (each an unbiased estimate, `largestep`).
        let seed_sum = b * n_seed as f64;
        let normalization = |stats: &[MutationStats]| {
            let (large_sum, large_n) = stats
                .iter()
                .filter(|s| s.name == MutationKind::LargeStep.name())
                .map(|s| (s.sums.get(largestep::B_ESTIMATE).copied().unwrap_or(0.0), s.proposed))
                .fold((0.0, 0), |(a, n), (x, m)| (a + x, n + m));
            (seed_sum + large_sum, n_seed as u64 + large_n)
        };
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
