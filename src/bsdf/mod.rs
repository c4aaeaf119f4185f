//! BSDFs: one plugin per file, as in Mitsuba 3. Every model works in the local shading frame
//! (normal = +z), evaluates, samples and reports the pdf in both transport directions, because
//! bidirectional methods and Metropolis mutations need all three for radiance and importance.
//!
//! Conventions: `wi` points towards the previous path vertex (where the path came from) and `wo`
//! towards the next one; both point away from the surface. `eval` returns f(wi, wo) WITHOUT the
//! cosine factor; `sample` returns weight = f * |cos θo| / pdf. Delta lobes are invisible to `eval`
//! and `pdf` (they return zero) and reachable only through `sample` (with `pdf` = the discrete lobe
//! probability, flagged by `BsdfLobe::is_delta`).

pub mod conductor;
pub mod dielectric;
pub mod diffuse;
pub mod fresnel;
pub mod ior;
pub mod microfacet;
pub mod plastic;
pub mod roughconductor;
pub mod roughdielectric;
pub mod roughplastic;
pub mod twosided;

use crate::props::{PropValue, Props, SceneError};
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};
use microfacet::MicrofacetKind;
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

/// Veach's correction for shading normals in importance transport (Veach 1997, §5.3): with a shading
/// normal `ns` that differs from the geometric `ng`, the adjoint BSDF seen by paths that start at a
/// light is f(wi, wo) · |wi·ns| |wo·ng| / (|wi·ng| |wo·ns|). Radiance transport needs no factor.
/// Directions are world-space and follow this module's convention (`wi` towards the previous vertex).
/// Returns 0 where a direction grazes the geometric surface, rather than an infinite weight.
pub fn shading_normal_correction(mode: TransportMode, wi: Vec3, wo: Vec3, ng: Vec3, ns: Vec3) -> f32 {
    if mode == TransportMode::Radiance {
        return 1.0;
    }
    let num = wi.dot(ns).abs() * wo.dot(ng).abs();
    let den = wi.dot(ng).abs() * wo.dot(ns).abs();
    if den <= 1e-12 || !num.is_finite() {
        return 0.0;
    }
    num / den
}

/// Builds a BSDF from its `<bsdf>` element.
pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<Arc<dyn Bsdf>, SceneError> {
    Ok(match props.plugin_type.as_str() {
        "diffuse" => Arc::new(diffuse::Diffuse::from_props(props, loader)?),
        "conductor" => Arc::new(conductor::SmoothConductor::from_props(props, loader)?),
        "roughconductor" => Arc::new(roughconductor::RoughConductor::from_props(props, loader)?),
        "dielectric" => Arc::new(dielectric::SmoothDielectric::from_props(props, loader)?),
        "roughdielectric" => Arc::new(roughdielectric::RoughDielectric::from_props(props, loader)?),
        "plastic" => Arc::new(plastic::SmoothPlastic::from_props(props, loader)?),
        "roughplastic" => Arc::new(roughplastic::RoughPlastic::from_props(props, loader)?),
        "twosided" => Arc::new(twosided::TwoSided::from_props(props, loader)?),
        other => {
            return Err(props.error(format!(
                "unsupported BSDF type '{other}' (supported: diffuse, conductor, roughconductor, \
                 dielectric, roughdielectric, plastic, roughplastic, twosided)"
            )))
        }
    })
}

impl BsdfLoader<'_> {
    /// A colour-or-texture parameter, relative file names resolved against `base_dir`.
    pub fn texture(&self, props: &Props, name: &str, default: Spectrum) -> Result<Texture, SceneError> {
        Texture::from_param_in(props, name, default, self.base_dir)
    }

    /// An optional colour-or-texture parameter (`None` when absent, so the BSDF can skip it).
    pub fn texture_opt(&self, props: &Props, name: &str) -> Result<Option<Texture>, SceneError> {
        if props.has(name) {
            Ok(Some(self.texture(props, name, Vec3::ONE)?))
        } else {
            Ok(None)
        }
    }
}

/// Reads `distribution` (`beckmann` or `ggx`, case-insensitive; Beckmann by default as in Mitsuba 3).
pub(crate) fn read_distribution(props: &Props) -> Result<MicrofacetKind, SceneError> {
    match props.string("distribution", "beckmann")?.to_ascii_lowercase().as_str() {
        "beckmann" => Ok(MicrofacetKind::Beckmann),
        "ggx" => Ok(MicrofacetKind::Ggx),
        other => Err(props
            .error_at("distribution", format!("invalid distribution '{other}' (expected beckmann or ggx)"))),
    }
}

fn read_roughness(props: &Props, name: &str) -> Result<Option<f32>, SceneError> {
    if let Some(PropValue::Object(_)) = props.get(name).map(|p| &p.value) {
        return Err(
            props.error_at(name, format!("textured roughness is not supported; give '{name}' as a float"))
        );
    }
    let v = props.float_opt(name)?;
    if let Some(a) = v {
        if !(a.is_finite() && a >= 0.0) {
            return Err(props.error_at(name, format!("'{name}' must be a non-negative number, got {a}")));
        }
    }
    Ok(v)
}

/// Reads `alpha` (default 0.1) or the anisotropic pair `alpha_u`/`alpha_v`, with Mitsuba 3's rules:
/// both of the pair or neither, and never together with `alpha`.
pub(crate) fn read_alpha(props: &Props) -> Result<(f32, f32), SceneError> {
    let au = read_roughness(props, "alpha_u")?;
    let av = read_roughness(props, "alpha_v")?;
    let a = read_roughness(props, "alpha")?;
    match (a, au, av) {
        (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
            Err(props.error("specify either 'alpha' or 'alpha_u'/'alpha_v', not both"))
        }
        (_, Some(u), Some(v)) => Ok((u, v)),
        (_, Some(_), None) | (_, None, Some(_)) => {
            Err(props.error("both 'alpha_u' and 'alpha_v' must be specified"))
        }
        (a, None, None) => {
            let a = a.unwrap_or(0.1);
            Ok((a, a))
        }
    }
}

/// Relative index int_ior/ext_ior from `int_ior`/`ext_ior` (numbers or names).
pub(crate) fn read_eta(props: &Props, int_default: &str, require_mismatch: bool) -> Result<f32, SceneError> {
    let int_ior = ior::read_ior(props, "int_ior", int_default)?;
    let ext_ior = ior::read_ior(props, "ext_ior", "air")?;
    if require_mismatch && int_ior == ext_ior {
        return Err(props.error("the interior and exterior indices of refraction must differ"));
    }
    Ok(int_ior / ext_ior)
}

/// Complex index of a conductor: `material` preset (default "none", an ideal mirror) or explicit `eta`/`k`.
pub(crate) fn read_conductor_ior(
    props: &Props,
    loader: &BsdfLoader,
) -> Result<(Texture, Texture), SceneError> {
    let material = props.string("material", "none")?;
    if props.has("eta") || props.has("k") || material == "none" {
        if material != "none" {
            return Err(props.error_at("material", "specify either 'material' or 'eta'/'k', not both"));
        }
        let eta = loader.texture(props, "eta", Vec3::ZERO)?;
        let k = loader.texture(props, "k", Vec3::ONE)?;
        return Ok((eta, k));
    }
    match ior::conductor_preset(&material) {
        Some((eta, k)) => Ok((Texture::Constant(eta), Texture::Constant(k))),
        None => Err(props.error_at(
            "material",
            format!(
                "unknown conductor material '{material}' (known: {})",
                ior::conductor_preset_names().join(", ")
            ),
        )),
    }
}

/// Replaces non-finite or negative results by zero: BSDFs never hand NaN/Inf to integrators.
pub(crate) fn sanitize(s: Spectrum) -> Spectrum {
    if s.is_finite() {
        s.max(Vec3::ZERO)
    } else {
        Vec3::ZERO
    }
}

/// Finishes a sample: rejects zero/non-finite pdfs and weights.
pub(crate) fn finish_sample(
    wo: Vec3,
    weight: Spectrum,
    pdf: f32,
    lobe: BsdfLobe,
    eta: f32,
) -> Option<BsdfSample> {
    if !(pdf > 0.0 && pdf.is_finite() && wo.is_finite() && weight.is_finite()) {
        return None;
    }
    if weight.max_element() <= 0.0 {
        return None;
    }
    Some(BsdfSample { wo, weight: weight.max(Vec3::ZERO), pdf, lobe, eta })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shading_normal_correction_is_one_without_bump_and_for_radiance() {
        let ng = Vec3::Z;
        let ns = Vec3::new(0.2, 0.0, 1.0).normalize();
        let wi = Vec3::new(0.3, 0.1, 0.9).normalize();
        let wo = Vec3::new(-0.5, 0.2, 0.6).normalize();
        assert_eq!(shading_normal_correction(TransportMode::Radiance, wi, wo, ng, ns), 1.0);
        let same = shading_normal_correction(TransportMode::Importance, wi, wo, ng, ng);
        assert!((same - 1.0).abs() < 1e-6);
        let c = shading_normal_correction(TransportMode::Importance, wi, wo, ng, ns);
        let expected = wi.dot(ns) * wo.dot(ng) / (wi.dot(ng) * wo.dot(ns));
        assert!((c - expected).abs() < 1e-6 && c != 1.0);
        let grazing = Vec3::new(1.0, 0.0, 0.0);
        assert_eq!(shading_normal_correction(TransportMode::Importance, grazing, wo, ng, ns), 0.0);
    }
}
