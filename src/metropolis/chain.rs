//! The generic Metropolis–Hastings chain (Metropolis et al. 1953, Hastings 1970; Veach 1997, ch. 11):
//! mutations propose a new state and the ratio of transition densities, the chain accepts with
//! a = min(1, f(y) T(y→x) / (f(x) T(x→y))) and records both states with expected values (Veach §11.3.4).

use crate::sampling::Sampler;
use crate::spectrum::{luminance, Spectrum};
use std::collections::BTreeMap;

/// Something a chain walks over: a path (Veach's MLT) or a primary-sample vector's sample (PSSMLT).
pub trait ChainState {
    /// The total measurement contribution that the target function scores, up to `scale`.
    fn contribution(&self) -> Spectrum;

    /// The factor f = `contribution` · scale, for states whose f lies outside f32's range (path-space
    /// paths through small near-specular objects); 1 for every other state.
    fn scale(&self) -> f64 {
        1.0
    }

    /// Whether every value the state would record is finite and non-negative; invalid proposals are
    /// rejected and counted, never recorded.
    fn is_valid(&self) -> bool {
        let c = self.contribution();
        c.is_finite() && c.min_element() >= 0.0
    }
}

/// The scalar the chain's stationary density is proportional to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TargetFunction {
    Luminance,
    /// Luminance raised to a power (< 1 flattens the distribution towards dim paths).
    LuminancePower(f64),
}

impl TargetFunction {
    /// The target of a bare contribution; a state is scored with `of`, which applies its scale.
    pub fn eval(self, contribution: Spectrum) -> f64 {
        let y = luminance(contribution) as f64;
        if !(y > 0.0) || !y.is_finite() {
            return 0.0;
        }
        match self {
            TargetFunction::Luminance => y,
            TargetFunction::LuminancePower(p) => y.powf(p),
        }
    }

    /// The target of a state, its scale included.
    pub fn of<S: ChainState + ?Sized>(self, state: &S) -> f64 {
        let y = self.eval(state.contribution());
        let scale = state.scale();
        let scaled = match self {
            TargetFunction::Luminance => y * scale,
            TargetFunction::LuminancePower(p) => y * scale.powf(p),
        };
        if scaled.is_finite() {
            scaled
        } else {
            0.0
        }
    }
}

/// A mutation's proposal: the new state y and T(y→x) / T(x→y), the ratio of the densities of proposing
/// the current state from y and of proposing y from the current state (1 for symmetric mutations).
#[derive(Clone, Debug)]
pub struct Proposal<S> {
    pub state: S,
    pub t_ratio: f64,
}

/// Why a mutation produced no proposal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Failure {
    /// The mutation does not apply to this state (e.g. HSLT on a path without glossy vertices); the
    /// chain stays and the state is recorded, as the mixture's selection probabilities intend.
    NotApplicable,
    /// The mutation applied but could not build a proposal; counted under `reason` (e.g. "occluded",
    /// "did_not_converge"), and the chain stays as after a rejection.
    Failed(&'static str),
}

/// A way of proposing a new state from the current one. `C` is the context the mutations of one chain
/// share (scene, integrator settings, PSSMLT's primary-sample vector); it is never shared between chains.
pub trait Mutation<S, C>: Send {
    fn name(&self) -> &'static str;

    /// A new state from `current`, or why there is none. `stats` is this mutation's record in the
    /// chain, for mutation-specific sums (`MutationStats::add_sum`: Newton iterations, step sizes).
    fn propose(
        &mut self,
        current: &S,
        ctx: &mut C,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<S>, Failure>;

    /// The chain moved to the last proposal.
    fn accepted(&mut self, _ctx: &mut C) {}

    /// The chain stayed; mutations with internal state (PSS vectors) restore it here.
    fn rejected(&mut self, _ctx: &mut C) {}
}

/// Per-mutation counts; `proposed = accepted + rejected + rejected_zero + rejected_invalid +
/// not_applicable + Σ failed`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MutationStats {
    pub name: &'static str,
    pub proposed: u64,
    pub accepted: u64,
    /// Rejected by the acceptance test.
    pub rejected: u64,
    /// Rejected because the proposal carries no contribution (target 0).
    pub rejected_zero: u64,
    /// Rejected because the proposal's contribution or density ratio was NaN, infinite or negative.
    pub rejected_invalid: u64,
    /// The mutation did not apply to the current state.
    pub not_applicable: u64,
    /// Sum of acceptance probabilities (mean acceptance = this / proposed).
    pub acceptance_sum: f64,
    /// Proposals the mutation could not build, by reason.
    pub failed: BTreeMap<&'static str, u64>,
    /// Mutation-specific sums (divide by a count for a mean), e.g. Newton iterations.
    pub sums: BTreeMap<&'static str, f64>,
    /// Proposals whose wall time was measured (every `TIME_EVERY`-th), and that time in seconds:
    /// the cost side of acceptance × cost when choosing a mixture.
    pub timed: u64,
    pub timed_seconds: f64,
}

/// One proposal in this many (per mutation) is timed: two clock reads cost about 50 ns, a tenth of
/// the cheapest proposal, so timing every one would bias the mixture's measured costs and slow it.
pub const TIME_EVERY: u64 = 16;

/// Consecutive rejections after which a chain counts as stuck: at an acceptance of even 10% the
/// chance of 1000 rejections in a row is 10⁻⁴⁶, so such a streak means a state the mutations
/// cannot leave (a rare path with a large contribution), whose image error the summary reports.
pub const STUCK_STREAK: u64 = 1000;

/// A chain's rejection streaks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Streaks {
    /// The longest run of consecutive rejections.
    pub longest: u64,
    /// Mutations spent in runs of at least `STUCK_STREAK` rejections (counted from the first).
    pub stuck_mutations: u64,
}

impl MutationStats {
    pub fn acceptance_rate(&self) -> f64 {
        if self.proposed == 0 {
            0.0
        } else {
            self.accepted as f64 / self.proposed as f64
        }
    }

    pub fn failed_total(&self) -> u64 {
        self.failed.values().sum()
    }

    pub fn add_sum(&mut self, key: &'static str, value: f64) {
        *self.sums.entry(key).or_insert(0.0) += value;
    }

    pub fn add(&mut self, o: &MutationStats) {
        self.proposed += o.proposed;
        self.accepted += o.accepted;
        self.rejected += o.rejected;
        self.rejected_zero += o.rejected_zero;
        self.rejected_invalid += o.rejected_invalid;
        self.not_applicable += o.not_applicable;
        self.acceptance_sum += o.acceptance_sum;
        for (k, v) in &o.failed {
            *self.failed.entry(k).or_insert(0) += v;
        }
        for (k, v) in &o.sums {
            *self.sums.entry(k).or_insert(0.0) += v;
        }
        self.timed += o.timed;
        self.timed_seconds += o.timed_seconds;
    }

    /// Mean wall time of a proposal (from the timed ones), in microseconds.
    pub fn microseconds_per_proposal(&self) -> Option<f64> {
        (self.timed > 0).then(|| self.timed_seconds / self.timed as f64 * 1e6)
    }
}

/// A mutation with its selection weight.
pub struct WeightedMutation<S, C> {
    pub mutation: Box<dyn Mutation<S, C>>,
    pub weight: f64,
}

/// One Markov chain. The caller supplies a starting state of non-zero target (drawn from the seeding
/// pass in proportion to its target, which removes start-up bias) and a recorder for states.
pub struct Chain<S, C> {
    current: S,
    current_target: f64,
    mutations: Vec<WeightedMutation<S, C>>,
    total_weight: f64,
    stats: Vec<MutationStats>,
    rng: Sampler,
    target: TargetFunction,
    /// The states the target is defined on; outside it the target is zero (direct-lighting paths when
    /// direct illumination is rendered separately). Everything by default.
    support: Option<Support<S>>,
    /// Consecutive rejections up to now, and the record so far.
    streak: u64,
    streaks: Streaks,
}

/// A predicate on states: `true` where the chain's target may be positive.
pub type Support<S> = Box<dyn Fn(&S) -> bool + Send>;

/// Failure reason under which proposals outside the chain's support are counted.
pub const OUTSIDE_SUPPORT: &str = "outside_support";

impl<S: ChainState, C> Chain<S, C> {
    /// `start` must have a positive, finite target; `rng` is the chain's own stream (from the seed and
    /// the chain index, never from the thread).
    pub fn new(
        start: S,
        mutations: Vec<WeightedMutation<S, C>>,
        target: TargetFunction,
        rng: Sampler,
    ) -> Chain<S, C> {
        let current_target = target.of(&start);
        assert!(current_target > 0.0 && current_target.is_finite(), "a chain must start where f > 0");
        assert!(!mutations.is_empty(), "a chain needs at least one mutation");
        let total_weight = mutations.iter().map(|m| m.weight.max(0.0)).sum::<f64>();
        assert!(total_weight > 0.0, "mutation weights must not all be zero");
        let stats = mutations
            .iter()
            .map(|m| MutationStats { name: m.mutation.name(), ..Default::default() })
            .collect();
        Chain {
            current: start,
            current_target,
            mutations,
            total_weight,
            stats,
            rng,
            target,
            support: None,
            streak: 0,
            streaks: Streaks::default(),
        }
    }

    /// Restricts the target to states for which `support` holds: proposals outside it are rejected
    /// like zero-contribution ones (counted as `OUTSIDE_SUPPORT`). The current state must be inside.
    pub fn with_support(mut self, support: Support<S>) -> Chain<S, C> {
        assert!(support(&self.current), "a chain must start inside its support");
        self.support = Some(support);
        self
    }

    pub fn current(&self) -> &S {
        &self.current
    }

    /// Moves the chain to `start`, a fresh draw from the seeds (so in the stationary distribution
    /// whatever the current state is), keeping its statistics and random stream; a rejection streak
    /// ends there. Returns false, leaving the chain where it is, when `start` has no positive, finite
    /// target or lies outside the support.
    pub fn restart(&mut self, start: S) -> bool {
        let start_target = self.target.of(&start);
        let inside = self.support.as_ref().is_none_or(|support| support(&start));
        if !(start_target > 0.0 && start_target.is_finite() && inside) {
            return false;
        }
        self.current = start;
        self.current_target = start_target;
        self.streak = 0;
        true
    }

    pub fn current_target(&self) -> f64 {
        self.current_target
    }

    pub fn stats(&self) -> &[MutationStats] {
        &self.stats
    }

    pub fn streaks(&self) -> Streaks {
        self.streaks
    }

    fn pick_mutation(&mut self) -> usize {
        let mut u = self.rng.next_f64() * self.total_weight;
        for (i, m) in self.mutations.iter().enumerate() {
            let w = m.weight.max(0.0);
            if u < w {
                return i;
            }
            u -= w;
        }
        // Rounding at the top end: the last mutation with positive weight.
        self.mutations.iter().rposition(|m| m.weight > 0.0).unwrap_or(0)
    }

    /// One mutation: propose, accept or reject, and record the proposed state with weight a / f(y) and
    /// the current one with weight (1 − a) / f(x) (expected values). `record(state, weight)` receives
    /// weights that already include 1/f, so the recorder only multiplies by the normalisation b.
    pub fn step(&mut self, ctx: &mut C, record: &mut impl FnMut(&S, f64)) {
        let which = self.pick_mutation();
        // Timing depends on the proposal count only, never on the random stream.
        let start = (self.stats[which].proposed % TIME_EVERY == 0).then(std::time::Instant::now);
        let accepted_before = self.stats[which].accepted;
        self.step_with(which, ctx, record);
        let stats = &mut self.stats[which];
        if let Some(start) = start {
            stats.timed += 1;
            stats.timed_seconds += start.elapsed().as_secs_f64();
        }
        if stats.accepted > accepted_before {
            self.streak = 0;
        } else {
            self.streak += 1;
            self.streaks.longest = self.streaks.longest.max(self.streak);
            if self.streak == STUCK_STREAK {
                self.streaks.stuck_mutations += STUCK_STREAK;
            } else if self.streak > STUCK_STREAK {
                self.streaks.stuck_mutations += 1;
            }
        }
    }

    fn step_with(&mut self, which: usize, ctx: &mut C, record: &mut impl FnMut(&S, f64)) {
        let stats = &mut self.stats[which];
        stats.proposed += 1;
        let mutation = &mut self.mutations[which].mutation;
        let proposal = match mutation.propose(&self.current, ctx, &mut self.rng, stats) {
            Ok(p) => p,
            Err(failure) => {
                match failure {
                    Failure::NotApplicable => stats.not_applicable += 1,
                    Failure::Failed(reason) => *stats.failed.entry(reason).or_insert(0) += 1,
                }
                mutation.rejected(ctx);
                record(&self.current, 1.0 / self.current_target);
                return;
            }
        };
        if self.support.as_ref().is_some_and(|inside| !inside(&proposal.state)) {
            *stats.failed.entry(OUTSIDE_SUPPORT).or_insert(0) += 1;
            mutation.rejected(ctx);
            record(&self.current, 1.0 / self.current_target);
            return;
        }
        let valid = proposal.state.is_valid() && proposal.t_ratio.is_finite() && proposal.t_ratio >= 0.0;
        let proposed_target = if valid { self.target.of(&proposal.state) } else { 0.0 };
        if !valid || !(proposed_target > 0.0) {
            if valid {
                stats.rejected_zero += 1;
            } else {
                stats.rejected_invalid += 1;
            }
            mutation.rejected(ctx);
            record(&self.current, 1.0 / self.current_target);
            return;
        }
        let a = (proposed_target * proposal.t_ratio / self.current_target).min(1.0);
        let a = if a.is_finite() { a } else { 0.0 };
        stats.acceptance_sum += a;
        if a > 0.0 {
            record(&proposal.state, a / proposed_target);
        }
        if a < 1.0 {
            record(&self.current, (1.0 - a) / self.current_target);
        }
        if self.rng.next_f64() < a {
            stats.accepted += 1;
            mutation.accepted(ctx);
            self.current = proposal.state;
            self.current_target = proposed_target;
        } else {
            stats.rejected += 1;
            mutation.rejected(ctx);
        }
    }
}
