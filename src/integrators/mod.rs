//! Integrators, one file each (pbrt-v4's separation of integrators from materials and samplers).
//! Pixel integrators estimate the measurement of one camera sample; the render loop in `render`
//! drives them over the film, so every integrator gets progress, time budgets and interruption for free.

mod path;

pub use path::PathTracer;

use crate::geometry::Ray;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// Per-sample counters an integrator may fill (summed over the render for reports).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SampleCounters {
    /// Rays cast (closest-hit and shadow).
    pub rays: u64,
}

impl std::ops::AddAssign for SampleCounters {
    fn add_assign(&mut self, o: SampleCounters) {
        self.rays += o.rays;
    }
}

/// An integrator that estimates radiance along camera rays independently per sample.
pub trait PixelIntegrator: Send + Sync {
    fn name(&self) -> &'static str;

    /// Radiance arriving along `-ray.dir` at the camera, estimated with the random stream `sampler`.
    fn li(&self, scene: &Scene, ray: &Ray, sampler: &mut Sampler, counters: &mut SampleCounters) -> Spectrum;
}

/// Path-length limits in Mitsuba 3's meaning (see `IntegratorSpec`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DepthLimits {
    /// Longest path in segments; -1 for unbounded.
    pub max_depth: i32,
    /// Russian roulette starts once a path has this many segments.
    pub rr_depth: i32,
}

/// The integrators the CLI can select.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntegratorKind {
    Path,
}

impl IntegratorKind {
    /// Parses a CLI or scene-file name (`pt` and Mitsuba's `path` are the same).
    pub fn parse(name: &str) -> Result<IntegratorKind, String> {
        match name {
            "pt" | "path" => Ok(IntegratorKind::Path),
            "bdpt" | "pssmlt" | "mlt" | "hslt" | "hslt+mlt" | "memlt" => {
                Err(format!("integrator '{name}' is not available in this build yet (available: pt)"))
            }
            other => Err(format!("unknown integrator '{other}' (available: pt)")),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            IntegratorKind::Path => "pt",
        }
    }
}

/// Builds a pixel integrator.
pub fn make(kind: IntegratorKind, limits: DepthLimits, hide_emitters: bool) -> Box<dyn PixelIntegrator> {
    match kind {
        IntegratorKind::Path => Box::new(PathTracer { limits, hide_emitters }),
    }
}
