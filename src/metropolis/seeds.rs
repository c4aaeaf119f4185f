//! The path-space seeding pass (Veach 1997, §11.3.1): independent BDPT samples, replayable by index,
//! whose weighted strategies' luminance gives b (the normalisation of the chains' image) and the
//! distribution the chains start from (`PathSeeds::draw`, in proportion to those weights).

use super::path_state::PathState;
use super::pssmlt::{sample_cdf, PssContext, Pssmlt};
use crate::integrators::{bdpt::Contribution, Bdpt};
use crate::render::SampleCounters;
use crate::scene::Scene;
use crate::spectrum::luminance;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Seed samples evaluated per parallel work item.
const SEED_CHUNK: usize = 4096;

/// Seed samples per extension of a time-limited seeding pass, at least.
const SEED_EXTENSION_MIN: usize = 2 * SEED_CHUNK;

/// Most seed samples a time-limited pass extends to: 2^28 keep 256 MiB of group sums (`SEED_GROUP`),
/// about ten minutes of seeding on two cores.
const SEED_PATHS_MAX: usize = 1 << 28;

/// Seed samples per group in a long pass: the seeding pass keeps one running sum per group, not per
/// strategy, and a draw replays the samples of its group to find the strategy (at most this many BDPT
/// samples). Memory is then about one byte per seed sample, so the pass can be long
/// (`mlt::SEED_TIME_SHARE`).
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
                let chunk_start = first + chunk * SEED_CHUNK;
                let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, chunk_start));
                for i in chunk_start..chunk_end {
                    if (i - first) % group == 0 {
                        out.groups.push((i, 0.0));
                    }
                    Pssmlt::restart_seed_pss(&mut ctx.pss, seed, i);
                    let _ = ctx.evaluate();
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
                out.rays += ctx.counters;
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
        let mut ctx = PssContext::new(scene, bdpt, Pssmlt::seed_pss(seed, self.group_first[g]));
        'samples: for i in self.group_first[g]..group_end {
            Pssmlt::restart_seed_pss(&mut ctx.pss, seed, i);
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
        Pssmlt::restart_seed_pss(&mut ctx.pss, seed, i);
        let (_, sub) = ctx.evaluate_with_paths();
        let contribution = ctx.contributions().get(j)?;
        PathState::new(scene, contribution.path(&sub))
    }
}

/// Runs more seed samples after `seeds` until `budget` has passed since `started`, in batches sized by
/// the rate so far (so the pass ends close to its budget), then appends them.
pub(super) fn extend_seeds(
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
