//! Primary sample space (Kelemen, Szirmay-Kalos, Antal & Csonka 2002): a lazily grown vector of uniform
//! numbers that a sampling routine consumes through `SampleSource`, mutated by large steps (fresh uniform
//! values) and small steps (Kelemen's exponential kernel, s1 = 1/1024, s2 = 1/64), as in pbrt-v3's MLTSampler.

use crate::sampling::{SampleSource, Sampler};

/// Smallest and largest small-step size of Kelemen's exponential kernel (their eq. 9).
pub const SMALL_STEP_S1: f64 = 1.0 / 1024.0;
pub const SMALL_STEP_S2: f64 = 1.0 / 64.0;

/// Pending small steps applied at most this many times when a long-unused dimension is read again. Any
/// number of applications of the symmetric kernel is itself symmetric, so the cap keeps detailed balance
/// while bounding the cost; dimensions the current state does not read do not change its contribution.
const MAX_PENDING_SMALL_STEPS: u64 = 32;

#[derive(Clone, Copy, Debug, Default)]
struct PrimarySample {
    value: f32,
    /// Iteration that last wrote `value` (lazy evaluation: older values still owe the steps since).
    last_modified: u64,
    backup_value: f32,
    backup_modified: u64,
}

/// A primary-sample-space vector with per-stream interleaved indices, so that one stream consuming more
/// numbers after a mutation does not shift the numbers the other streams read.
#[derive(Clone, Debug)]
pub struct PssSampler {
    rng: Sampler,
    samples: Vec<PrimarySample>,
    stream_count: usize,
    stream: usize,
    index_in_stream: usize,
    iteration: u64,
    large_step: bool,
    last_large_step: u64,
}

impl PssSampler {
    /// A fresh vector whose values are drawn lazily from `rng`; `stream_count` sub-streams are interleaved.
    pub fn new(rng: Sampler, stream_count: usize) -> PssSampler {
        PssSampler {
            rng,
            samples: Vec::new(),
            stream_count: stream_count.max(1),
            stream: 0,
            index_in_stream: 0,
            iteration: 0,
            large_step: true,
            last_large_step: 0,
        }
    }

    /// Starts over as `PssSampler::new(rng, ..)` would, keeping the vector's allocation: the seeding
    /// pass evaluates millions of fresh vectors, and growing each one from empty was 3% of an
    /// HSLT render's instructions.
    pub fn restart(&mut self, rng: Sampler) {
        let mut samples = std::mem::take(&mut self.samples);
        samples.clear();
        *self = PssSampler { samples, ..PssSampler::new(rng, self.stream_count) };
    }

    /// Replaces the stream future values are drawn from (values already realised stay). Chains started
    /// from the same seed sample use this to diverge.
    pub fn reseed(&mut self, rng: Sampler) {
        self.rng = rng;
    }

    /// Begins a proposal: a large step regenerates every value read from now on, a small step perturbs it.
    pub fn start_iteration(&mut self, large_step: bool) {
        self.iteration += 1;
        self.large_step = large_step;
        self.stream = 0;
        self.index_in_stream = 0;
    }

    pub fn is_large_step(&self) -> bool {
        self.large_step
    }

    /// Keeps the proposal as the new current vector.
    pub fn accept(&mut self) {
        if self.large_step {
            self.last_large_step = self.iteration;
        }
    }

    /// Restores every value the proposal touched, bit for bit.
    pub fn reject(&mut self) {
        for s in &mut self.samples {
            if s.last_modified == self.iteration {
                s.value = s.backup_value;
                s.last_modified = s.backup_modified;
            }
        }
        self.iteration -= 1;
    }

    /// The current vector as far as it has been read, for inspection and tests: `None` for dimensions
    /// not read since the last accepted large step, whose value is a fresh uniform number not drawn yet
    /// (lazy evaluation); dimensions never read are absent.
    pub fn values(&self) -> Vec<Option<f32>> {
        self.samples.iter().map(|s| (s.last_modified >= self.last_large_step).then_some(s.value)).collect()
    }

    /// One small step of the exponential kernel around `x`, wrapped to [0, 1).
    fn small_step(rng: &mut Sampler, x: f32) -> f32 {
        let magnitude = SMALL_STEP_S2 * (-(SMALL_STEP_S2 / SMALL_STEP_S1).ln() * rng.next_f64()).exp();
        let moved = if rng.next_1d() < 0.5 { x as f64 + magnitude } else { x as f64 - magnitude };
        wrap_unit(moved)
    }

    fn ensure_ready(&mut self, index: usize) -> f32 {
        let (iteration, large, last_large) = (self.iteration, self.large_step, self.last_large_step);
        let rng = &mut self.rng;
        while self.samples.len() <= index {
            // A dimension read for the first time has been uniform since the last large step (its
            // pending small steps keep it uniform), so it is realised as a fresh uniform of that age.
            let value = rng.next_1d();
            self.samples.push(PrimarySample { value, last_modified: last_large, ..Default::default() });
        }
        let s = &mut self.samples[index];
        // Read again within the same proposal (a stream restarted): it already has this state's value,
        // and backing it up again would lose the previous state's.
        if s.last_modified == iteration {
            return s.value;
        }
        // A value older than the last accepted large step was regenerated by it (lazily, now).
        if s.last_modified < last_large {
            s.value = rng.next_1d();
            s.last_modified = last_large;
        }
        s.backup_value = s.value;
        s.backup_modified = s.last_modified;
        if large {
            s.value = rng.next_1d();
        } else {
            let pending = (iteration - s.last_modified).min(MAX_PENDING_SMALL_STEPS);
            for _ in 0..pending {
                s.value = Self::small_step(rng, s.value);
            }
        }
        s.last_modified = iteration;
        s.value
    }
}

/// x mod 1 in [0, 1); rounding can land exactly on 1, which wraps to 0.
fn wrap_unit(x: f64) -> f32 {
    let v = (x - x.floor()) as f32;
    if v >= 1.0 || !(v >= 0.0) {
        0.0
    } else {
        v
    }
}

impl SampleSource for PssSampler {
    fn next_1d(&mut self) -> f32 {
        let index = self.index_in_stream * self.stream_count + self.stream;
        self.index_in_stream += 1;
        self.ensure_ready(index)
    }

    fn start_stream(&mut self, index: usize) {
        debug_assert!(index < self.stream_count, "stream {index} of {}", self.stream_count);
        self.stream = index % self.stream_count;
        self.index_in_stream = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_stays_in_unit_interval() {
        for x in [-1e-9, 1.0 - 1e-12, 1.0, 2.5, -0.25, 0.0] {
            let v = wrap_unit(x);
            assert!((0.0..1.0).contains(&v), "{x} -> {v}");
        }
        assert_eq!(wrap_unit(-0.25), 0.75);
    }
}
