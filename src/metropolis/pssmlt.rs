//! Primary-sample-space MLT (Kelemen et al. 2002) over bidirectional path tracing, as in pbrt-v3's MLT
//! integrator: a state is one BDPT sample driven by a primary-sample vector, the target is the luminance
//! of its total contribution, and the image is b / (f · mutations per pixel) times the recorded splats.

use super::chain::{
    Chain, ChainState, Failure, Mutation, MutationStats, Proposal, TargetFunction, WeightedMutation,
};
use super::direct;
use super::driver::{self, ChainRunner, CountsRays, FilmState, RunningChain};
use super::pss::PssSampler;
use crate::geometry::Vec2;
use crate::integrators::{
    bdpt::{Contribution, Subpaths},
    Bdpt,
};
use crate::render::{
    Film, Integrator, RenderOptions, RenderOutput, RenderStats, SampleCounters, Splat, Work,
};
use crate::sampling::{SampleSource, Sampler};
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// BDPT uses streams 0 (camera walk), 1 (light walk) and 2 (connections); the film position has its own.
const STREAM_COUNT: usize = 4;
const FILM_STREAM: usize = 3;

/// Third index of `Sampler::new` for each purpose, so seed samples and chains never share a stream.
const SEED_STREAM: u64 = 0x5EED;
const CHAIN_STREAM: u64 = 0xC4A1;
const CHAIN_PSS_STREAM: u64 = 0xC4A2;

/// Seed samples evaluated per parallel work item.
const SEED_CHUNK: usize = 4096;

/// PSSMLT parameters (CLI: `--seed-paths`, `--chains`, `--p-large`).
#[derive(Clone, Debug, PartialEq)]
pub struct PssmltSettings {
    /// Independent BDPT samples of the seeding pass; `None` = four per pixel, at least 16 384 and at
    /// most 2^20.
    pub seed_paths: Option<usize>,
    /// Number of Markov chains; fixed rather than derived from the thread count so images are the same
    /// on any machine.
    pub chains: usize,
    /// Probability of a large step (a fresh, independent sample).
    pub p_large: f64,
    pub target: TargetFunction,
    /// The separate direct-illumination pass (`metropolis::direct`); `Off` lets the chains render
    /// direct illumination too.
    pub direct: direct::DirectPass,
}

impl Default for PssmltSettings {
    fn default() -> PssmltSettings {
        PssmltSettings {
            seed_paths: None,
            chains: 64,
            p_large: 0.3,
            target: TargetFunction::Luminance,
            direct: direct::DirectPass::Auto,
        }
    }
}

impl PssmltSettings {
    pub fn seed_paths_for(&self, pixels: usize) -> usize {
        self.seed_paths.unwrap_or_else(|| (4 * pixels).clamp(16_384, 1 << 20)).max(1)
    }
}

pub struct Pssmlt {
    pub bdpt: Bdpt,
    pub settings: PssmltSettings,
}

/// One BDPT sample as a chain state: its weighted strategy estimates at their film positions.
#[derive(Clone, Debug, Default)]
pub struct PssSample {
    pub splats: Vec<(Vec2, Spectrum)>,
    /// Sum of the splat values: what the target function scores.
    pub contribution: Spectrum,
}

impl ChainState for PssSample {
    fn contribution(&self) -> Spectrum {
        self.contribution
    }

    fn is_valid(&self) -> bool {
        self.splats.iter().all(|(_, v)| v.is_finite() && v.min_element() >= 0.0)
            && self.contribution.is_finite()
    }
}

/// What the mutations of one chain share: the primary-sample vector and the BDPT it drives.
pub struct PssContext<'a> {
    pub scene: &'a Scene,
    pub bdpt: &'a Bdpt,
    pub pss: PssSampler,
    pub counters: SampleCounters,
    scratch: Vec<Contribution>,
}

impl<'a> PssContext<'a> {
    pub fn new(scene: &'a Scene, bdpt: &'a Bdpt, pss: PssSampler) -> PssContext<'a> {
        PssContext { scene, bdpt, pss, counters: SampleCounters::default(), scratch: Vec::new() }
    }

    /// Runs BDPT on the current primary-sample vector. The film position is uniform over the image,
    /// the density BDPT's light-tracing (t = 1) weights assume for camera samples.
    pub fn evaluate(&mut self) -> PssSample {
        self.evaluate_with_paths().0
    }

    /// As `evaluate`, also returning the sub-paths; `contributions()` then lists the strategies, from
    /// which path-space MLT rebuilds whole paths (`Contribution::path`).
    pub fn evaluate_with_paths(&mut self) -> (PssSample, Subpaths) {
        let (w, h) = (self.scene.film.width as f32, self.scene.film.height as f32);
        self.pss.start_stream(FILM_STREAM);
        let u = self.pss.next_2d();
        // u < 1, but u·w can round up to w; keep the position inside the image.
        let pos = Vec2::new((u.x * w).min(w * (1.0 - f32::EPSILON)), (u.y * h).min(h * (1.0 - f32::EPSILON)));
        let ray = self.scene.camera.generate_ray(pos);
        self.scratch.clear();
        let sub = self.bdpt.sample(self.scene, &ray, &mut self.pss, &mut self.counters, &mut self.scratch);
        let mut sample = PssSample { splats: Vec::with_capacity(self.scratch.len()), ..Default::default() };
        for c in &self.scratch {
            sample.splats.push((c.film.unwrap_or(pos), c.value));
            sample.contribution += c.value;
        }
        (sample, sub)
    }

    /// The strategies of the last evaluation.
    pub fn contributions(&self) -> &[Contribution] {
        &self.scratch
    }
}

/// Kelemen's two mutations of the primary-sample vector; both are symmetric (T(y→x) = T(x→y)).
pub struct PssStep {
    pub large: bool,
    /// Scores large steps: they are independent samples, so their mean target refines b.
    pub target: TargetFunction,
}

/// Key of the large steps' summed target in their `MutationStats::sums`.
const LARGE_STEP_TARGET: &str = "target";

impl<'a> Mutation<PssSample, PssContext<'a>> for PssStep {
    fn name(&self) -> &'static str {
        if self.large {
            "large_step"
        } else {
            "small_step"
        }
    }

    fn propose(
        &mut self,
        _current: &PssSample,
        ctx: &mut PssContext<'a>,
        _rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PssSample>, Failure> {
        ctx.pss.start_iteration(self.large);
        let state = ctx.evaluate();
        if self.large {
            let y = if state.is_valid() { self.target.of(&state) } else { 0.0 };
            stats.add_sum(LARGE_STEP_TARGET, y);
        }
        Ok(Proposal { state, t_ratio: 1.0 })
    }

    fn accepted(&mut self, ctx: &mut PssContext<'a>) {
        ctx.pss.accept();
    }

    fn rejected(&mut self, ctx: &mut PssContext<'a>) {
        ctx.pss.reject();
    }
}

impl Pssmlt {
    /// With `settings.direct` enabled the chains run on `bdpt` without its direct-lighting paths
    /// (`direct::chain_bdpt`), which the render estimates separately.
    pub fn new(bdpt: Bdpt, settings: PssmltSettings) -> Pssmlt {
        Pssmlt { bdpt: direct::chain_bdpt(bdpt, settings.direct), settings }
    }

    /// The primary-sample vector of seed sample `index` (replayable: chains restart from it).
    pub fn seed_pss(seed: u64, index: usize) -> PssSampler {
        PssSampler::new(Self::seed_stream(seed, index), STREAM_COUNT)
    }

    /// Turns `pss` into `seed_pss(seed, index)` without allocating.
    pub fn restart_seed_pss(pss: &mut PssSampler, seed: u64, index: usize) {
        pss.restart(Self::seed_stream(seed, index));
    }

    fn seed_stream(seed: u64, index: usize) -> Sampler {
        Sampler::new(seed, index as u64, SEED_STREAM)
    }

    fn mutations(&self) -> Vec<WeightedMutation<PssSample, PssContext<'_>>> {
        let p_large = self.settings.p_large.clamp(0.0, 1.0);
        let target = self.settings.target;
        vec![
            WeightedMutation { mutation: Box::new(PssStep { large: true, target }), weight: p_large },
            WeightedMutation { mutation: Box::new(PssStep { large: false, target }), weight: 1.0 - p_large },
        ]
    }

    /// Chain `chain_index`, started from the seed sample at `position` of the cumulative weights
    /// (`driver::systematic_position`), so drawn in proportion to its target: the chain is then in its
    /// stationary distribution from the first mutation, so no start-up samples are discarded.
    /// `cdf` runs over the seed samples from index `first_seed` on.
    fn start_chain<'a>(
        &'a self,
        scene: &'a Scene,
        seed: u64,
        chain_index: usize,
        position: f64,
        cdf: &[f64],
        first_seed: usize,
    ) -> Option<ChainRunner<PssSample, PssContext<'a>>> {
        let rng = Sampler::new(seed, chain_index as u64, CHAIN_STREAM);
        let start_index = first_seed + sample_cdf(cdf, position)?;
        let mut ctx = PssContext::new(scene, &self.bdpt, Self::seed_pss(seed, start_index));
        let start = ctx.evaluate();
        // Chains that start from the same seed sample must still diverge.
        ctx.pss.reseed(Sampler::new(seed, chain_index as u64, CHAIN_PSS_STREAM));
        let target = self.settings.target;
        if !(start.is_valid() && target.of(&start) > 0.0) {
            // Replaying a seed sample is deterministic, so this means the seed pass itself was wrong.
            debug_assert!(false, "seed sample {start_index} does not replay");
            return None;
        }
        Some(ChainRunner { chain: Chain::new(start, self.mutations(), target, rng), ctx })
    }
}

/// Index drawn from a cumulative table with probability proportional to each entry's increment.
pub fn sample_cdf(cdf: &[f64], u: f64) -> Option<usize> {
    let total = *cdf.last()?;
    if !(total > 0.0) {
        return None;
    }
    let x = u * total;
    Some(cdf.partition_point(|&c| c <= x).min(cdf.len() - 1))
}

impl FilmState for PssSample {
    fn splat(&self, weight: f64, out: &mut Vec<Splat>) {
        out.extend(self.splats.iter().map(|&(pos, value)| Splat {
            pos,
            value: value * weight as f32,
            layer: None,
        }));
    }
}

impl CountsRays for PssContext<'_> {
    fn rays(&self) -> u64 {
        self.counters.rays
    }

    fn shadow_rays(&self) -> u64 {
        self.counters.shadow_rays
    }
}

impl Integrator for Pssmlt {
    fn name(&self) -> &'static str {
        "pssmlt"
    }

    fn render(&self, scene: &Scene, options: &RenderOptions, cancel: &AtomicBool) -> RenderOutput {
        let start_time = Instant::now();
        let (width, height) = (scene.film.width, scene.film.height);
        let pixels = (width * height).max(1);
        let mut film = Film::with_filter(width, height, scene.film.rfilter);
        let mut stats = RenderStats::default();
        let mut metadata: Vec<(String, String)> = Vec::new();
        let target = self.settings.target;
        let direct = self.settings.direct;
        direct::render_into(&mut film, scene, &self.bdpt, direct, options, cancel, &mut stats, &mut metadata);

        // Runs that continue an earlier one (`first_sample` > 0) must be independent of it.
        let seed = options.seed ^ (options.first_sample as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        // Seeding pass: independent BDPT samples estimate b = E[f] and give the chains their start. A
        // share of the render (`--part`) takes its share of the seed samples' indices, and of the chains.
        let seed_range = options.share.range(self.settings.seed_paths_for(pixels) as u64);
        let first_seed = seed_range.start as usize;
        let n_seed = (seed_range.end - seed_range.start) as usize;
        let chunks: Vec<(Vec<f64>, u64, SampleCounters)> = (0..n_seed.div_ceil(SEED_CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let range =
                    first_seed + chunk * SEED_CHUNK..first_seed + ((chunk + 1) * SEED_CHUNK).min(n_seed);
                let (mut targets, mut invalid, mut rays) =
                    (Vec::with_capacity(range.len()), 0, SampleCounters::default());
                if cancel.load(Ordering::Relaxed) {
                    return (vec![0.0; range.len()], 0, rays);
                }
                let mut ctx = PssContext::new(scene, &self.bdpt, Self::seed_pss(seed, range.start));
                for i in range {
                    Self::restart_seed_pss(&mut ctx.pss, seed, i);
                    let sample = ctx.evaluate();
                    if sample.is_valid() {
                        targets.push(target.of(&sample));
                    } else {
                        invalid += 1;
                        targets.push(0.0);
                    }
                }
                rays += ctx.counters;
                (targets, invalid, rays)
            })
            .collect();
        let mut cdf = Vec::with_capacity(n_seed);
        let mut sum = 0.0f64;
        for (targets, invalid, rays) in &chunks {
            stats.invalid_samples += invalid;
            stats.rays += rays.rays;
            stats.shadow_rays += rays.shadow_rays;
            for &t in targets {
                sum += t;
                cdf.push(sum);
            }
        }
        drop(chunks);
        let b = if n_seed > 0 { sum / n_seed as f64 } else { 0.0 };
        let nonzero_seeds = cdf.windows(2).filter(|w| w[1] > w[0]).count()
            + usize::from(cdf.first().is_some_and(|&c| c > 0.0));
        metadata.push(("hslt.mlt.seed_paths".into(), n_seed.to_string()));
        metadata.push(("hslt.mlt.seed_paths_nonzero".into(), nonzero_seeds.to_string()));
        metadata.push(("hslt.mlt.normalization".into(), format!("{b:.6e}")));
        if cancel.load(Ordering::Relaxed) {
            stats.interrupted = true;
        }
        if !(b > 0.0 && b.is_finite()) || stats.interrupted {
            if !stats.interrupted {
                metadata.push(("hslt.mlt.status".into(), driver::empty_seeding_status(n_seed, &self.bdpt)));
            }
            // An interrupted seeding pass left samples out of its sum, so it counts for nothing; a
            // complete one that found nothing still tells a merge that b is small.
            let work = match stats.interrupted {
                true => Work::Chains { mutations: 0, b_sum: 0.0, b_samples: 0 },
                false => Work::Chains { mutations: 0, b_sum: sum, b_samples: n_seed as u64 },
            };
            film.splat_scale = 0.0;
            stats.elapsed = start_time.elapsed();
            return RenderOutput { film, stats, metadata, work };
        }

        // Work: spp keeps its meaning of work per pixel; with only a time limit, chains run until it.
        let total_mutations = driver::total_mutations(options, scene);
        let chain_range = driver::chain_range(options, self.settings.chains, total_mutations);
        let n_chains = chain_range.len();
        let chains_start = Instant::now();
        let first_chain = chain_range.start;
        let mut chains: Vec<Box<dyn RunningChain + '_>> = chain_range
            .into_par_iter()
            .filter_map(|c| {
                let position = driver::systematic_position(seed, CHAIN_STREAM, c - first_chain, n_chains);
                self.start_chain(scene, seed, c, position, &cdf, first_seed)
            })
            .map(|c| Box::new(c) as Box<dyn RunningChain + '_>)
            .collect();
        let quotas = driver::quotas(total_mutations, chains.len());
        // b from the seeding pass and every large step: both are independent BDPT samples, and the
        // large steps outnumber the seeds by far in long renders.
        let seed_sum = sum;
        let normalization = |stats: &[MutationStats]| {
            let (large_sum, large_n) = stats
                .iter()
                .filter(|s| s.name == "large_step")
                .map(|s| (s.sums.get(LARGE_STEP_TARGET).copied().unwrap_or(0.0), s.proposed))
                .fold((0.0, 0), |(a, n), (x, m)| (a + x, n + m));
            (seed_sum + large_sum, n_seed as u64 + large_n)
        };
        let outcome =
            driver::drive(options, cancel, start_time, normalization, film, &mut chains, &quotas, |stats| {
                acceptance_extra(stats)
            });
        let (b_sum, b_samples) = normalization(&outcome.stats);
        metadata.push(("hslt.mlt.normalization_final".into(), format!("{:.6e}", b_sum / b_samples as f64)));
        film = outcome.film;
        let work = outcome.work;
        metadata.extend(driver::streak_metadata(&outcome.streaks, outcome.mutations));
        let mutation_stats = outcome.stats;
        let mutations_done = outcome.mutations;
        stats.rays += outcome.rays;
        stats.shadow_rays += outcome.shadow_rays;
        stats.interrupted |= outcome.interrupted;
        if cancel.load(Ordering::Relaxed) {
            stats.interrupted = true;
        }
        // Each recorded state weighs 1/f; b/f summed over M mutations estimates the image times M/(w h)
        // (the driver sets the film's scale accordingly).
        stats.samples = mutations_done;
        stats.min_spp = (mutations_done / pixels as u64).min(u32::MAX as u64) as u32;
        stats.passes = 1;
        stats.invalid_samples += mutation_stats.iter().map(|s| s.rejected_invalid).sum::<u64>();
        stats.elapsed = start_time.elapsed();

        metadata.push(("hslt.mlt.chains".into(), n_chains.to_string()));
        metadata.push(("hslt.mlt.mutations".into(), mutations_done.to_string()));
        metadata.extend(driver::mutation_metadata(&mutation_stats));
        metadata.push((
            "hslt.mlt.seconds_seeding".into(),
            format!("{:.3}", driver::seconds(start_time, chains_start)),
        ));
        RenderOutput { film, stats, metadata, work }
    }
}

/// The overall acceptance rate, for snapshots (the comparison report plots it).
pub fn acceptance_extra(stats: &[MutationStats]) -> Vec<(String, String)> {
    let proposed: u64 = stats.iter().map(|s| s.proposed).sum();
    let accepted: u64 = stats.iter().map(|s| s.accepted).sum();
    let rate = if proposed > 0 { accepted as f64 / proposed as f64 } else { 0.0 };
    vec![("acceptance_rate".into(), format!("{rate:.4}"))]
}
