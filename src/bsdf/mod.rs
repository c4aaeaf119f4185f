//! BSDFs: one plugin per file, as in Mitsuba 3. Every model works in the local shading frame
//! (normal = +z), evaluates, samples and reports the pdf in both transport directions, because
//! bidirectional methods and Metropolis mutations need all three for radiance and importance.
//!
//! Conventions: `wi` points towards the previous path vertex (where the path came from) and `wo`
//! towards the next one; both point away from the surface. `eval` returns f(wi, wo) WITHOUT the
//! cosine factor; `sample` returns weight = f * |cos θo| / pdf. Delta lobes are invisible to `eval`
//! and `pdf` (they return zero) and reachable only through `sample` (with `pdf` = the discrete lobe
//! probability, flagged by `BsdfLobe::is_delta`).

use crate::scene::{Props, SceneError};
use crate::spectrum::Spectrum;
use glam::{Vec2, Vec3};
use std::fmt::Debug;
use std::path::Path;
use std::sync::Arc;

/// Which quantity a path carries, needed for the adjoint BSDF (non-symmetric refraction scaling).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransportMode {
    /// The path started at the sensor and carries radiance-like throughput to the lights.
    Radiance,
    /// The path started at a light and carries importance-like throughput to the sensor.
    Importance,
}

impl TransportMode {
    pub fn flip(self) -> TransportMode {
        match self {
            TransportMode::Radiance => TransportMode::Importance,
            TransportMode::Importance => TransportMode::Radiance,
        }
    }
}

/// Per-query context: the transport direction and the surface's texture coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfContext {
    pub mode: TransportMode,
    pub uv: Vec2,
}

/// Lobe classification, as a bit set. Diffuse/glossy/delta matter for the manifold walk's
/// vertex classes; reflection/transmission for MIS and Russian roulette.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct BsdfLobe(pub u32);

impl BsdfLobe {
    pub const NONE: BsdfLobe = BsdfLobe(0);
    pub const DIFFUSE_REFLECTION: BsdfLobe = BsdfLobe(1);
    pub const GLOSSY_REFLECTION: BsdfLobe = BsdfLobe(2);
    pub const DELTA_REFLECTION: BsdfLobe = BsdfLobe(4);
    pub const DIFFUSE_TRANSMISSION: BsdfLobe = BsdfLobe(8);
    pub const GLOSSY_TRANSMISSION: BsdfLobe = BsdfLobe(16);
    pub const DELTA_TRANSMISSION: BsdfLobe = BsdfLobe(32);
    pub const DIFFUSE: BsdfLobe = BsdfLobe(1 | 8);
    pub const GLOSSY: BsdfLobe = BsdfLobe(2 | 16);
    pub const DELTA: BsdfLobe = BsdfLobe(4 | 32);
    pub const REFLECTION: BsdfLobe = BsdfLobe(1 | 2 | 4);
    pub const TRANSMISSION: BsdfLobe = BsdfLobe(8 | 16 | 32);

    pub fn contains(self, other: BsdfLobe) -> bool {
        self.0 & other.0 != 0
    }
    pub fn is_delta(self) -> bool {
        self.contains(BsdfLobe::DELTA)
    }
    /// True if any lobe is not a delta, i.e. `eval` can be non-zero.
    pub fn has_smooth(self) -> bool {
        self.contains(BsdfLobe::DIFFUSE) || self.contains(BsdfLobe::GLOSSY)
    }
}

impl std::ops::BitOr for BsdfLobe {
    type Output = BsdfLobe;
    fn bitor(self, rhs: BsdfLobe) -> BsdfLobe {
        BsdfLobe(self.0 | rhs.0)
    }
}

/// The outcome of sampling a BSDF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    /// Sampled direction in the local frame.
    pub wo: Vec3,
    /// f * |cos θo| / pdf, including the radiance-mode 1/η² factor for refraction.
    pub weight: Spectrum,
    /// Solid-angle pdf (for delta lobes: the probability of having picked that lobe).
    pub pdf: f32,
    /// The single lobe that produced the sample.
    pub lobe: BsdfLobe,
    /// Relative index of refraction η_t/η_i across the surface for this sample; 1 for reflection.
    pub eta: f32,
}

pub trait Bsdf: Send + Sync + Debug {
    /// All lobes this BSDF has (may depend on nothing but construction parameters).
    fn lobes(&self) -> BsdfLobe;

    /// f(wi, wo) for the non-delta lobes, no cosine factor.
    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum;

    /// Solid-angle density with which `sample` produces `wo` given `wi`, non-delta lobes only.
    fn pdf(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32;

    /// Samples `wo` given `wi`; `u_lobe` picks a lobe, `u` samples within it.
    fn sample(&self, ctx: &BsdfContext, wi: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample>;

    /// Smallest microfacet roughness α over the BSDF's lobes: 0 for pure delta BSDFs,
    /// `f32::INFINITY` for purely diffuse ones. The manifold walk classifies vertices by it.
    fn roughness(&self) -> f32;

    /// Interior/exterior index ratio for BSDFs that refract; 1 otherwise.
    fn eta(&self) -> f32 {
        1.0
    }
}

/// Loads any BSDF texture through `read_texture`, resolving relative file names against `base_dir`.
pub struct BsdfLoader<'a> {
    pub base_dir: &'a Path,
}

/// Builds a BSDF from its `<bsdf>` element (placeholder until the BSDF library lands).
pub fn from_props(props: &Props, _loader: &BsdfLoader) -> Result<Arc<dyn Bsdf>, SceneError> {
    Err(props.error(format!("unsupported BSDF type '{}'", props.plugin_type)))
}
