//! Runs many Metropolis chains side by side (rayon) in rounds, shared by PSSMLT and path-space MLT:
//! each round every chain advances on its own random stream and buffers what it records; the buffers
//! are then added to one film in chain order, so the image depends on the seed alone, never on
//! scheduling or thread count. Rounds end at snapshot times, the time limit and cancellation.

use super::chain::{Chain, ChainState, MutationStats, Streaks, STUCK_STREAK};
use crate::render::{Film, RenderOptions, RenderState, Snapshot, SnapshotClock, Splat, Work};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Mutations between checks of the clock and the cancel flag.
const CHECK_EVERY: u64 = 256;
/// Most mutations one chain runs per round: bounds the delay before a snapshot or the end of the render.
const ROUND_MUTATIONS: u64 = 1 << 14;
/// Most mutations all chains run per round together: bounds the buffered splats (memory) however
/// many chains there are (64 chains get the full `ROUND_MUTATIONS` each).
const ROUND_TOTAL: u64 = 1 << 20;
/// Fewest mutations per chain and round, so many chains still amortise a round's overhead.
const ROUND_MIN: u64 = 256;

/// A chain state that can say what it adds to the film.
pub trait FilmState: ChainState {
    /// Appends the splats of this state recorded with `weight` (which already holds 1/f).
    fn splat(&self, weight: f64, out: &mut Vec<Splat>);
}

/// A chain context that counts the rays it casts.
pub trait CountsRays {
    fn rays(&self) -> u64;
    /// Of `rays`, the shadow rays.
    fn shadow_rays(&self) -> u64;
}

/// A chain with everything it needs to advance, behind one object so different state spaces share
/// the driver.
pub trait RunningChain: Send {
    /// Runs at most `max` mutations, stopping early once `deadline` passes or `cancel` is set, and
    /// appends the recorded splats (unnormalised) to `out`. Returns the number of mutations run.
    fn advance(
        &mut self,
        max: u64,
        deadline: Option<Instant>,
        cancel: &AtomicBool,
        out: &mut Vec<Splat>,
    ) -> u64;
    fn stats(&self) -> &[MutationStats];
    fn rays(&self) -> u64;
    fn shadow_rays(&self) -> u64;
    fn streaks(&self) -> Streaks;
    /// Restarts from fresh seed draws so far (chains that never restart: 0).
    fn restarts(&self) -> u64 {
        0
    }
    /// Restart points passed whose seed draw gave no path that evaluates, so the chain went on from
    /// where it was (unbiased either way: restart points do not depend on the state).
    fn failed_restarts(&self) -> u64 {
        0
    }
}

/// A `Chain` with its context.
pub struct ChainRunner<S, C> {
    pub chain: Chain<S, C>,
    pub ctx: C,
}

impl<S: FilmState + Send, C: CountsRays + Send> RunningChain for ChainRunner<S, C> {
    fn advance(
        &mut self,
        max: u64,
        deadline: Option<Instant>,
        cancel: &AtomicBool,
        out: &mut Vec<Splat>,
    ) -> u64 {
        let mut record = |state: &S, weight: f64| state.splat(weight, out);
        let mut done = 0;
        while done < max {
            if done % CHECK_EVERY == 0
                && (cancel.load(Ordering::Relaxed) || deadline.is_some_and(|d| Instant::now() >= d))
            {
                break;
            }
            self.chain.step(&mut self.ctx, &mut record);
            done += 1;
        }
        done
    }

    fn stats(&self) -> &[MutationStats] {
        self.chain.stats()
    }

    fn rays(&self) -> u64 {
        self.ctx.rays()
    }

    fn shadow_rays(&self) -> u64 {
        self.ctx.shadow_rays()
    }

    fn streaks(&self) -> Streaks {
        self.chain.streaks()
    }
}

/// What the chains did.
#[derive(Debug)]
pub struct DriveOutcome {
    /// The image: recorded splats scaled by b · pixels / mutations.
    pub film: Film,
    pub mutations: u64,
    pub stats: Vec<MutationStats>,
    pub rays: u64,
    pub shadow_rays: u64,
    pub interrupted: bool,
    /// Each chain's rejection streaks.
    pub streaks: Vec<Streaks>,
    /// The work behind the film: mutations, and b as a sum over independent samples.
    pub work: Work,
}

/// Work per chain: `total` mutations split evenly, or unbounded (`u64::MAX`) when only a time limit
/// ends the render.
pub fn quotas(total: u64, chains: usize) -> Vec<u64> {
    // No chains (none found a starting path): no work, and `drive` returns the film as it is.
    let n = chains as u64;
    (0..n).map(|c| if total == u64::MAX { u64::MAX } else { total / n + u64::from(c < total % n) }).collect()
}

/// Mutations a render runs in all: `spp` keeps its meaning of work per pixel (this share's part of it
/// for `--part`), and with only a time limit chains run until it (`u64::MAX`).
pub fn total_mutations(options: &RenderOptions, scene: &crate::scene::Scene) -> u64 {
    let pixels = (scene.film.width * scene.film.height).max(1) as u64;
    let spp = match (options.spp, options.time_limit) {
        (Some(spp), _) => spp.max(1),
        (None, Some(_)) => return u64::MAX,
        (None, None) => scene.spp.max(1),
    };
    let range = options.share.range(spp as u64 * pixels);
    (range.end - range.start).saturating_sub(options.mutations_done)
}

/// Where chain `index` of a render's `count` chains looks up its start in the seeding pass's
/// cumulative weights: systematic resampling, (index + u₀) / count with one offset u₀ per render
/// (from `seed` and `stream`). Each position is uniform, so each chain still starts in proportion to
/// the seeds' weights (in its stationary distribution, unbiased), but the number of chains starting in
/// a family of paths holding a share p of b is ⌊p·count⌋ or ⌈p·count⌉ rather than binomial, and
/// chains that mix slowly between families keep most of their energy where they started (Douc and
/// Cappé 2005 compare the resampling schemes; Veach's and pbrt's chains draw independently).
pub fn systematic_position(seed: u64, stream: u64, index: usize, count: usize) -> f64 {
    let offset = crate::sampling::Sampler::new(seed, u64::MAX, stream).next_f64();
    ((index as f64 + offset) / count.max(1) as f64).min(1.0)
}

/// Indices of this render's chains: `chains` of them (no more than there are mutations to run), or
/// this share's part of them; a chain's random streams derive from its index.
pub fn chain_range(options: &RenderOptions, chains: usize, total_mutations: u64) -> std::ops::Range<usize> {
    let all = options.share.range(chains.max(1) as u64);
    let share = (all.end - all.start).min(total_mutations.min(1 << 32));
    all.start as usize..(all.start + share) as usize
}

/// Sums per-mutation statistics over chains (chains list their mutations in the same order).
pub fn merge_stats<'a>(all: impl IntoIterator<Item = &'a [MutationStats]>) -> Vec<MutationStats> {
    let mut merged: Vec<MutationStats> = Vec::new();
    for stats in all {
        if merged.is_empty() {
            merged = stats.to_vec();
        } else {
            for (acc, s) in merged.iter_mut().zip(stats) {
                acc.add(s);
            }
        }
    }
    merged
}

/// Runs `chains` until their quotas are done, the time limit passes or `cancel` is set; calls the
/// snapshot hook of `options` between rounds. `normalization` gives b, the mean target over the whole
/// state space, as a sum of independent estimates and their count, from the merged statistics so far
/// (the seeding pass's, refined by large steps); `started` is when `render` began.
#[allow(clippy::too_many_arguments)]
pub fn drive(
    options: &RenderOptions,
    cancel: &AtomicBool,
    started: Instant,
    normalization: impl Fn(&[MutationStats]) -> (f64, u64),
    mut film: Film,
    chains: &mut [Box<dyn RunningChain + '_>],
    quotas: &[u64],
    snapshot_extra: impl Fn(&[MutationStats]) -> Vec<(String, String)>,
) -> DriveOutcome {
    assert_eq!(chains.len(), quotas.len());
    let pixels = film.width * film.height;
    let work = |stats: &[MutationStats], mutations: u64| {
        let (b_sum, b_samples) = normalization(stats);
        Work::Chains { mutations, b_sum, b_samples }
    };
    let deadline = options.time_limit.map(|l| started + l);
    let mut remaining: Vec<u64> = quotas.to_vec();
    let mut clock = SnapshotClock::new(options);
    let mut mutations = 0u64;
    let mut buffers: Vec<Vec<Splat>> = chains.iter().map(|_| Vec::new()).collect();
    let per_round = (ROUND_TOTAL / chains.len().max(1) as u64).clamp(ROUND_MIN, ROUND_MUTATIONS);
    loop {
        if remaining.iter().all(|&r| r == 0) || cancel.load(Ordering::Relaxed) {
            break;
        }
        if deadline.is_some_and(|d| Instant::now() >= d) {
            break;
        }
        // A round ends at the next snapshot time so the hook sees the image close to when it asked.
        let snapshot_at = clock.next_time().map(|t| started + t);
        let round_deadline = match (deadline, snapshot_at) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let done: Vec<u64> = chains
            .par_iter_mut()
            .zip(buffers.par_iter_mut())
            .zip(remaining.par_iter())
            .map(|((chain, buffer), &left)| {
                buffer.clear();
                chain.advance(left.min(per_round), round_deadline, cancel, buffer)
            })
            .collect();
        for ((left, d), buffer) in remaining.iter_mut().zip(&done).zip(&buffers) {
            *left = left.saturating_sub(*d);
            mutations += d;
            for splat in buffer {
                film.add_splat(splat);
            }
        }
        let wants_state = clock.wants_state();
        clock.poll(started.elapsed(), || {
            let stats = merge_stats(chains.iter().map(|c| c.stats()));
            let work = work(&stats, mutations);
            film.splat_scale = work.splat_scale(pixels);
            Snapshot {
                elapsed: started.elapsed(),
                image: film.to_image(),
                samples: mutations,
                spp: (mutations as f64 / pixels.max(1) as f64) as u32,
                extra: snapshot_extra(&stats),
                state: wants_state.then(|| RenderState::new(film.clone(), work)),
            }
        });
        // A round that ran nothing (deadline reached inside every chain) ends the loop next time round.
        if done.iter().all(|&d| d == 0) && round_deadline == deadline {
            break;
        }
    }
    let stats = merge_stats(chains.iter().map(|c| c.stats()));
    let rays = chains.iter().map(|c| c.rays()).sum();
    let work = work(&stats, mutations);
    film.splat_scale = work.splat_scale(pixels);
    let streaks = chains.iter().map(|c| c.streaks()).collect();
    let shadow_rays = chains.iter().map(|c| c.shadow_rays()).sum();
    let interrupted = cancel.load(Ordering::Relaxed);
    DriveOutcome { film, mutations, stats, rays, shadow_rays, interrupted, streaks, work }
}

/// Metadata keys `hslt.mlt.<mutation>.<what>` for each mutation: counts, acceptance, failure reasons
/// and the means of mutation-specific sums (per proposal).
pub fn mutation_metadata(stats: &[MutationStats]) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let proposed: u64 = stats.iter().map(|s| s.proposed).sum();
    let accepted: u64 = stats.iter().map(|s| s.accepted).sum();
    out.push((
        "hslt.mlt.acceptance".into(),
        format!("{:.4}", if proposed > 0 { accepted as f64 / proposed as f64 } else { 0.0 }),
    ));
    for s in stats {
        let key = |what: &str| format!("hslt.mlt.{}.{what}", s.name);
        out.push((key("proposed"), s.proposed.to_string()));
        out.push((key("accepted"), s.accepted.to_string()));
        out.push((key("rejected_zero"), s.rejected_zero.to_string()));
        out.push((key("rejected_invalid"), s.rejected_invalid.to_string()));
        out.push((key("not_applicable"), s.not_applicable.to_string()));
        out.push((key("acceptance"), format!("{:.4}", s.acceptance_rate())));
        for (reason, n) in &s.failed {
            out.push((key(&format!("failed.{reason}")), n.to_string()));
        }
        if let Some(us) = s.microseconds_per_proposal() {
            out.push((key("microseconds_per_proposal"), format!("{us:.3}")));
        }
        for (what, sum) in &s.sums {
            let applied = s.proposed - s.not_applicable;
            let mean = if applied > 0 { sum / applied as f64 } else { 0.0 };
            out.push((key(&format!("mean.{what}")), format!("{mean:.6}")));
        }
    }
    out
}

/// Metadata on stuck chains: how many had a run of `STUCK_STREAK` or more rejections, the longest
/// run, and the share of all mutations spent in such runs (where one state keeps collecting weight).
pub fn streak_metadata(streaks: &[Streaks], mutations: u64) -> Vec<(String, String)> {
    let stuck = streaks.iter().filter(|s| s.longest >= STUCK_STREAK).count();
    let longest = streaks.iter().map(|s| s.longest).max().unwrap_or(0);
    let stuck_mutations: u64 = streaks.iter().map(|s| s.stuck_mutations).sum();
    let share = if mutations > 0 { stuck_mutations as f64 / mutations as f64 } else { 0.0 };
    vec![
        ("hslt.mlt.chains_stuck".into(), stuck.to_string()),
        ("hslt.mlt.longest_rejection_streak".into(), longest.to_string()),
        ("hslt.mlt.stuck_share".into(), format!("{share:.4}")),
    ]
}

/// Seconds between two instants, for metadata.
pub fn seconds(from: Instant, to: Instant) -> f64 {
    to.saturating_duration_since(from).as_secs_f64()
}

/// What the image holds when the seeding pass found nothing for the chains.
pub fn empty_seeding_status(seed_paths: usize, chain_bdpt: &crate::integrators::Bdpt) -> String {
    if chain_bdpt.min_path_vertices > 2 {
        format!(
            "no light-carrying path of three or more segments among {seed_paths} seed paths: the image \
             holds the separately rendered direct illumination only"
        )
    } else {
        format!(
            "no light-carrying path among {seed_paths} seed paths (lights hidden or blocked?): the image is black"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::systematic_position;
    use crate::metropolis::pssmlt::sample_cdf;

    /// Chains per seed under systematic resampling: ⌊p·n⌋ or ⌈p·n⌉ for every seed, whatever the
    /// render's seed, where independent draws scatter binomially.
    #[test]
    fn systematic_positions_start_each_seed_its_share_of_chains() {
        let weights = [0.5, 3.0, 0.02, 7.25, 1.0, 0.0, 4.4, 0.13];
        let total: f64 = weights.iter().sum();
        let cdf: Vec<f64> = weights
            .iter()
            .scan(0.0, |sum, w| {
                *sum += w;
                Some(*sum)
            })
            .collect();
        let n = 1000;
        for seed in 0..50 {
            let mut counts = [0usize; 8];
            for i in 0..n {
                let u = systematic_position(seed, 7, i, n);
                assert!((0.0..=1.0).contains(&u), "position {u}");
                counts[sample_cdf(&cdf, u).unwrap()] += 1;
            }
            for (w, c) in weights.iter().zip(counts) {
                let share = w / total * n as f64;
                assert!(
                    c as f64 >= share.floor() && c as f64 <= share.ceil(),
                    "seed {seed}: {c} chains for {share}"
                );
            }
        }
    }

    /// Each chain's position is uniform over renders (so its start is drawn in proportion to the
    /// weights): the mean over many render seeds of chain i's position is (i + ½)/n.
    #[test]
    fn a_chains_systematic_position_is_uniform_over_render_seeds() {
        let (n, renders) = (16, 20_000);
        for i in [0, 7, 15] {
            let mean: f64 =
                (0..renders).map(|s| systematic_position(s, 3, i, n)).sum::<f64>() / renders as f64;
            let expected = (i as f64 + 0.5) / n as f64;
            // The offset's standard deviation is 0.29 of 1/n, so the mean's over 20 000 renders is
            // 2e-3 of 1/n: 1e-2 is five of them (a fixed offset of 0 would be 0.5 off).
            assert!((mean - expected).abs() < 1e-2 / n as f64, "chain {i}: mean {mean}, expected {expected}");
        }
    }
}
