//! Ray-query backends. The renderer asks only "what does this ray hit first" and "is this segment
//! blocked", for one ray or a batch; Embree (through FFI) answers by default, and a pure-Rust
//! BVH (`obvhs`) answers the same queries so the two can be compared on the same scene.

pub mod bvh;
pub mod embree;
pub mod timed;

pub use bvh::BvhScene;
pub use embree::{embree_version, set_flush_denormals, EmbreeScene};

use crate::geometry::{Ray, TriangleMesh};
use glam::Vec4;

/// The first intersection along a ray. `geom_id` indexes the mesh list given to the backend,
/// `prim_id` the triangle inside it; `(u, v)` are barycentrics: p = (1-u-v) p0 + u p1 + v p2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub geom_id: u32,
    pub prim_id: u32,
    pub u: f32,
    pub v: f32,
}

/// A backend's answer to ray queries over a fixed set of world-space triangle meshes.
pub trait RayQuery: Send + Sync {
    /// Short name for reports ("embree", "bvh").
    fn name(&self) -> &'static str;

    /// Closest hit with `ray.tmin < t < ray.tmax` (up to a few ulps: shorten shadow segments slightly).
    fn intersect(&self, ray: &Ray) -> Option<Hit>;

    /// True if anything lies on the ray with `ray.tmin < t < ray.tmax`.
    fn occluded(&self, ray: &Ray) -> bool;

    /// Closest hits for many rays at once; `hits.len() == rays.len()`.
    fn intersect_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        for (r, h) in rays.iter().zip(hits.iter_mut()) {
            *h = self.intersect(r);
        }
    }

    /// Occlusion for many rays at once; `occluded.len() == rays.len()`.
    fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) {
        for (r, o) in rays.iter().zip(occluded.iter_mut()) {
            *o = self.occluded(r);
        }
    }
}

/// The query interval of a ray that can hit something, `(max(tmin, 0), tmax)`, or `None` for rays
/// every backend treats as a miss: non-finite origin or direction, zero direction, NaN bounds or an
/// empty interval. Backends share it so they agree on degenerate input.
// Every single-ray query runs this, so it is written as one combined test with a single branch at
// the end instead of a chain of early returns (see docs/benchmarks.md, "Wrapper overhead").
#[inline]
pub fn query_interval(ray: &Ray) -> Option<(f32, f32)> {
    let (o, d) = (ray.origin, ray.dir);
    // x * 0 is 0 for finite x and NaN for infinities and NaN, so one 4-wide multiply-add and compare
    // tests all six components (glam's Vec4 is one SSE/NEON register).
    let (a, b) = (Vec4::new(o.x, o.y, o.z, d.x), Vec4::new(d.y, d.z, d.z, d.z));
    let finite = (a * 0.0 + b * 0.0).cmpeq(Vec4::ZERO).all();
    let nonzero = Vec4::new(d.x, d.y, d.z, d.z).cmpne(Vec4::ZERO).any();
    // The renderer never asks for hits behind the origin, and Embree requires tnear >= 0. `max`
    // would turn a NaN tmin into 0, so NaN is tested separately; a NaN tmax fails `tmin < tmax`.
    let tmin = ray.tmin.max(0.0);
    let ok = finite & nonzero & !ray.tmin.is_nan() & (tmin < ray.tmax);
    ok.then_some((tmin, ray.tmax))
}

/// A backend over no geometry: every ray misses.
pub struct NoGeometry;

impl RayQuery for NoGeometry {
    fn name(&self) -> &'static str {
        "none"
    }
    fn intersect(&self, _ray: &Ray) -> Option<Hit> {
        None
    }
    fn occluded(&self, _ray: &Ray) -> bool {
        false
    }
}

/// Which backend to build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AccelKind {
    /// Embree's default triangle test, which rounds as Mitsuba 3's (the same library and flags).
    #[default]
    Embree,
    /// Embree's robust (watertight) mode: rays aimed exactly at a shared edge or vertex never slip
    /// through, at some speed, and coincident faces then split differently from Mitsuba's.
    EmbreeRobust,
    /// Pure-Rust compressed wide BVH (`obvhs`) with a watertight triangle test.
    Bvh,
}

impl AccelKind {
    /// Peak bytes per triangle that building this backend's structure takes beyond the meshes
    /// themselves, with a margin: on 2000 tessellated spheres (32.8 M triangles) the build added 118
    /// bytes per triangle for Embree and 297 for the Rust BVH to the 39 the meshes hold. The scene
    /// loader checks this against the memory left before it commits to a build.
    pub fn build_bytes_per_triangle(self) -> u64 {
        match self {
            AccelKind::Embree | AccelKind::EmbreeRobust => 128,
            AccelKind::Bvh => 320,
        }
    }
}

/// Builds the acceleration structure for `meshes` with the chosen backend. The meshes may be owned,
/// borrowed or shared (`Arc<TriangleMesh>`): the backends copy what they need, so there is no reason
/// for the caller to clone its meshes first.
pub fn build<M: std::borrow::Borrow<TriangleMesh>>(
    kind: AccelKind,
    meshes: &[M],
) -> anyhow::Result<Box<dyn RayQuery>> {
    match kind {
        AccelKind::Embree => Ok(Box::new(embree::EmbreeScene::build(meshes)?)),
        AccelKind::EmbreeRobust => Ok(Box::new(embree::EmbreeScene::build_robust(meshes)?)),
        AccelKind::Bvh => Ok(Box::new(bvh::BvhScene::build(meshes)?)),
    }
}
