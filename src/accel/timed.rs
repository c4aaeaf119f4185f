//! A ray-query wrapper that measures the wall time spent inside the wrapped backend, for the
//! benchmark's "share of time in ray queries" figure. Instrumentation costs a clock read per call,
//! so it is used only in a separate, instrumented run.

use super::{Hit, RayQuery};
use crate::geometry::Ray;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Time and call count accumulated by a `TimedQuery`, shared with whoever reads the result.
#[derive(Debug, Default)]
pub struct QueryClock {
    nanos: AtomicU64,
    calls: AtomicU64,
}

impl QueryClock {
    /// Seconds inside the backend, less the measured cost of the clock reads themselves.
    pub fn corrected_seconds(&self) -> f64 {
        let raw = self.nanos.load(Ordering::Relaxed) as f64 * 1e-9;
        let calls = self.calls.load(Ordering::Relaxed) as f64;
        (raw - calls * clock_overhead_seconds()).max(0.0)
    }

    pub fn calls(&self) -> u64 {
        self.calls.load(Ordering::Relaxed)
    }
}

/// What one timed interval around an empty call measures (the clock's own cost), median of 5 runs.
pub fn clock_overhead_seconds() -> f64 {
    let mut runs: Vec<f64> = (0..5)
        .map(|_| {
            let n = 200_000;
            let mut total = 0u128;
            for _ in 0..n {
                let t = Instant::now();
                std::hint::black_box(());
                total += t.elapsed().as_nanos();
            }
            total as f64 * 1e-9 / n as f64
        })
        .collect();
    runs.sort_by(f64::total_cmp);
    runs[2]
}

pub struct TimedQuery {
    inner: Box<dyn RayQuery>,
    clock: Arc<QueryClock>,
}

impl TimedQuery {
    pub fn new(inner: Box<dyn RayQuery>, clock: Arc<QueryClock>) -> TimedQuery {
        TimedQuery { inner, clock }
    }

    fn timed<T>(&self, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let r = f();
        self.clock.nanos.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.clock.calls.fetch_add(1, Ordering::Relaxed);
        r
    }
}

impl RayQuery for TimedQuery {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.timed(|| self.inner.intersect(ray))
    }
    fn occluded(&self, ray: &Ray) -> bool {
        self.timed(|| self.inner.occluded(ray))
    }
    fn intersect_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        self.timed(|| self.inner.intersect_batch(rays, hits))
    }
    fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) {
        self.timed(|| self.inner.occluded_batch(rays, occluded))
    }
}
