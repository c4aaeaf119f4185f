//! The integrator interface every rendering technique implements, and the shared tile loop's side of
//! it: a pixel integrator estimates the measurement of one camera sample (pbrt-v4's separation of
//! integrators from the loop that drives them); a full `Integrator` (Metropolis chains) runs its own loop.

use super::{Film, RenderOptions, RenderStats, Splat, Work};
use crate::geometry::Ray;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use std::sync::atomic::AtomicBool;

/// Per-sample counters an integrator may fill (summed over the render for reports).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SampleCounters {
    /// Rays cast (closest-hit and shadow).
    pub rays: u64,
    /// Of those, shadow rays (visibility between two points).
    pub shadow_rays: u64,
}

impl std::ops::AddAssign for SampleCounters {
    fn add_assign(&mut self, o: SampleCounters) {
        self.rays += o.rays;
        self.shadow_rays += o.shadow_rays;
    }
}

/// What one camera sample produces besides the radiance at its own pixel.
#[derive(Debug, Default)]
pub struct SampleOutput {
    pub counters: SampleCounters,
    /// Contributions to other pixels (light tracing); the render loop scales them by 1/spp.
    pub splats: Vec<Splat>,
    /// Values for the integrator's extra layers at this sample's own pixel.
    pub layer_values: Vec<(u16, Spectrum)>,
}

/// An integrator that estimates radiance along camera rays independently per sample; the shared render
/// loop in `render` drives it over the film.
pub trait PixelIntegrator: Send + Sync {
    fn name(&self) -> &'static str;

    /// Radiance arriving along `-ray.dir` at the camera, estimated with the random stream `sampler`.
    fn li(&self, scene: &Scene, ray: &Ray, sampler: &mut Sampler, out: &mut SampleOutput) -> Spectrum;

    /// Whether `li` emits splats (light tracing); the render loop then keeps passes short so the
    /// per-pass splat lists stay small, and never keeps a partial pass.
    fn splats(&self) -> bool {
        false
    }

    /// Names of extra film layers (indices in `SampleOutput::layer_values` and `Splat::layer` follow
    /// this order).
    fn layers(&self) -> Vec<String> {
        Vec::new()
    }

    /// Whether layer values may be negative (normals); radiance layers may not, and a sample with a
    /// negative one is dropped as invalid like a NaN.
    fn signed_layers(&self) -> bool {
        false
    }
}

/// The finished result of a render.
#[derive(Debug)]
pub struct RenderOutput {
    pub film: Film,
    pub stats: RenderStats,
    /// Integrator-specific statistics for the output's metadata (e.g. Metropolis acceptance rates).
    pub metadata: Vec<(String, String)>,
    /// The work behind the film, for merging it with other renders (`RenderState`).
    pub work: Work,
}

/// Any rendering technique: pixel integrators run in the shared tile loop, Metropolis methods run
/// their chains. Progress, time budgets, cancellation and snapshots come through `RenderOptions`.
pub trait Integrator: Send + Sync {
    fn name(&self) -> &'static str;

    fn render(&self, scene: &Scene, options: &RenderOptions, cancel: &AtomicBool) -> RenderOutput;
}

/// Runs a pixel integrator in the shared render loop.
pub struct TiledRenderer(pub Box<dyn PixelIntegrator>);

impl Integrator for TiledRenderer {
    fn name(&self) -> &'static str {
        self.0.name()
    }

    fn render(&self, scene: &Scene, options: &RenderOptions, cancel: &AtomicBool) -> RenderOutput {
        let (film, stats) = super::render(scene, self.0.as_ref(), options, cancel);
        let work = Work::Pixels { spp: stats.min_spp as u64 };
        RenderOutput { film, stats, metadata: Vec::new(), work }
    }
}

/// Path-length limits in Mitsuba 3's meaning (see `IntegratorSpec`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DepthLimits {
    /// Longest path in segments; -1 for unbounded.
    pub max_depth: i32,
    /// Russian roulette starts once a path has this many segments.
    pub rr_depth: i32,
}

impl DepthLimits {
    /// The limits the scene's `<integrator>` element asks for.
    pub fn of_scene(scene: &Scene) -> DepthLimits {
        DepthLimits { max_depth: scene.integrator.max_depth, rr_depth: scene.integrator.rr_depth }
    }
}
