//! A ray-query wrapper that measures the wall time spent inside the wrapped backend, for the
//! benchmark's "share of time in ray queries" figure. Instrumentation costs a clock read per call,
//! so it is used only in a separate, instrumented run.

use super::{Hit, RayQuery};
use crate::geometry::Ray;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

pub struct TimedQuery {
    inner: Box<dyn RayQuery>,
    nanos: Arc<AtomicU64>,
}

impl TimedQuery {
    pub fn new(inner: Box<dyn RayQuery>, nanos: Arc<AtomicU64>) -> TimedQuery {
        TimedQuery { inner, nanos }
    }

    fn timed<T>(&self, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let r = f();
        self.nanos.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
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
