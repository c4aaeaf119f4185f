//! Emitters and light selection. Each emitter samples a point or direction as seen from a shading
//! point (next-event estimation) and reports the solid-angle density of doing so, so integrators can
//! weight it against BSDF sampling with multiple importance sampling (Veach 1997, ch. 9).

mod area;
mod envmap;
mod point;
mod spot;

pub use area::{AreaLight, SurfacePoint};
pub use envmap::EnvMap;
pub use point::PointLight;
pub use spot::SpotLight;

use crate::sampling::Distribution1D;
use crate::scene::{Props, SceneError};
use crate::spectrum::{luminance, Spectrum};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// A light sample as seen from a reference point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Position on the light (for infinite lights: a point far along `wi`).
    pub p: Vec3,
    /// Unit direction from the reference point towards the light.
    pub wi: Vec3,
    /// Distance to `p` (infinite for environment lights).
    pub dist: f32,
    /// Emitted radiance (or intensity / dist² for point-like lights) arriving along `-wi`.
    pub radiance: Spectrum,
    /// Solid-angle density at the reference point (1 for delta lights, which are flagged).
    pub pdf: f32,
    pub is_delta: bool,
}

#[derive(Debug)]
pub enum Light {
    Area(AreaLight),
    Point(PointLight),
    Spot(SpotLight),
    /// Uniform radiance from every direction (`constant`).
    Constant {
        radiance: Spectrum,
    },
    Env(EnvMap),
}

impl Light {
    /// Builds a light from a top-level `<emitter>` (area lights are built with their shape instead).
    pub fn from_props(props: &Props, base_dir: &std::path::Path) -> Result<Light, SceneError> {
        match props.plugin_type.as_str() {
            "point" => Ok(Light::Point(PointLight::from_props(props)?)),
            "spot" => Ok(Light::Spot(SpotLight::from_props(props)?)),
            "constant" => {
                props.expect_only(&["radiance"], &[])?;
                let radiance = props.rgb("radiance", Vec3::ONE)?;
                check_emission(props, "radiance", radiance)?;
                Ok(Light::Constant { radiance })
            }
            "envmap" => Ok(Light::Env(EnvMap::from_props(props, base_dir)?)),
            "area" => Err(props.error("an area emitter must be nested inside a <shape>")),
            other => Err(props.error(format!(
                "unsupported emitter type '{other}' (supported: area, point, spot, constant, envmap)"
            ))),
        }
    }

    pub fn is_delta(&self) -> bool {
        matches!(self, Light::Point(_) | Light::Spot(_))
    }

    pub fn is_infinite(&self) -> bool {
        matches!(self, Light::Constant { .. } | Light::Env(_))
    }

    /// Samples incident illumination at `p`.
    pub fn sample_li(&self, p: Vec3, u: Vec2, scene_radius: f32) -> Option<LightSample> {
        match self {
            Light::Area(a) => a.sample_li(p, u),
            Light::Point(l) => l.sample_li(p),
            Light::Spot(l) => l.sample_li(p),
            Light::Constant { radiance } => {
                let wi = crate::sampling::square_to_uniform_sphere(u);
                let dist = f32::INFINITY;
                Some(LightSample {
                    p: p + wi * 2.0 * scene_radius,
                    wi,
                    dist,
                    radiance: *radiance,
                    pdf: crate::sampling::uniform_sphere_pdf(),
                    is_delta: false,
                })
            }
            Light::Env(e) => e.sample_li(p, u, scene_radius),
        }
    }

    /// Radiance an infinite light sends along `-dir` (i.e. seen when looking along `dir`).
    pub fn eval_infinite(&self, dir: Vec3) -> Spectrum {
        match self {
            Light::Constant { radiance } => *radiance,
            Light::Env(e) => e.eval(dir),
            _ => Spectrum::ZERO,
        }
    }

    /// Solid-angle density with which `sample_li` picks direction `dir` for an infinite light.
    pub fn pdf_infinite(&self, dir: Vec3) -> f32 {
        match self {
            Light::Constant { .. } => crate::sampling::uniform_sphere_pdf(),
            Light::Env(e) => e.pdf(dir),
            _ => 0.0,
        }
    }

    /// Approximate emitted power (luminance), used only to choose lights in proportion to it.
    pub fn power(&self, scene_radius: f32) -> f32 {
        let r2 = scene_radius * scene_radius;
        match self {
            Light::Area(a) => a.power(),
            Light::Point(l) => 4.0 * PI * luminance(l.intensity),
            Light::Spot(l) => l.power(),
            Light::Constant { radiance } => PI * PI * r2 * 4.0 * luminance(*radiance),
            Light::Env(e) => PI * PI * r2 * 4.0 * e.mean_luminance(),
        }
    }
}

pub(crate) fn check_emission(props: &Props, name: &str, value: Spectrum) -> Result<(), SceneError> {
    if !value.is_finite() || value.min_element() < 0.0 {
        return Err(props.error_at(name, format!("'{name}' must be finite and non-negative, got {value}")));
    }
    Ok(())
}

/// Chooses a light in proportion to its estimated power; every light with non-zero power keeps a
/// non-zero probability so no emitter is silently ignored.
#[derive(Debug, Clone)]
pub struct LightSelector {
    distr: Option<Distribution1D>,
}

impl LightSelector {
    pub fn new(lights: &[Light], scene_radius: f32) -> LightSelector {
        let powers: Vec<f64> = lights
            .iter()
            .map(|l| {
                let p = l.power(scene_radius) as f64;
                if p.is_finite() && p > 0.0 {
                    p
                } else {
                    0.0
                }
            })
            .collect();
        let total: f64 = powers.iter().sum();
        // Mix with a uniform share so lights whose power estimate is poor are still found.
        let weights: Vec<f64> = powers
            .iter()
            .map(|&p| if p > 0.0 { 0.9 * p / total + 0.1 / lights.len() as f64 } else { 0.0 })
            .collect();
        LightSelector { distr: Distribution1D::new(&weights) }
    }

    pub fn is_empty(&self) -> bool {
        self.distr.is_none()
    }

    /// Picks a light: (index, probability, rescaled u).
    pub fn sample(&self, u: f32) -> Option<(usize, f32, f32)> {
        let d = self.distr.as_ref()?;
        let (i, r) = d.sample(u);
        Some((i, d.pmf(i), r))
    }

    pub fn pmf(&self, light: usize) -> f32 {
        self.distr.as_ref().map_or(0.0, |d| d.pmf(light))
    }
}
