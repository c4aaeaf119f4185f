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

use crate::props::{Props, SceneError};
use crate::sampling::Distribution1D;
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

/// A ray of emitted light, as light tracing starts it (Veach 1997, §10.3): a point with its area
/// density and a direction with its solid-angle density.
#[derive(Clone, Copy, Debug)]
pub struct EmissionSample {
    /// Start point; for infinite lights a point on a disk outside the scene facing `dir`.
    pub p: Vec3,
    /// Geometric normal on the emitting side (area lights); zero for point-like and infinite lights.
    pub ng: Vec3,
    /// Direction the light travels.
    pub dir: Vec3,
    /// Radiance (area, infinite) or intensity (point, spot) sent along `dir`.
    pub le: Spectrum,
    /// Density of `p`: per unit area (area lights; per unit disk area for infinite lights) or 1 for
    /// delta positions.
    pub pdf_pos: f32,
    /// Solid-angle density of `dir`.
    pub pdf_dir: f32,
    /// For area lights: the triangle and surface coordinates of `p`.
    pub surface: Option<SurfacePoint>,
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

    /// Samples an emitted ray: `u_pos` picks the point, `u_dir` the direction. `centre` and
    /// `scene_radius` bound the scene (for the disk that infinite lights start from).
    pub fn sample_le(
        &self,
        u_pos: Vec2,
        u_dir: Vec2,
        centre: Vec3,
        scene_radius: f32,
    ) -> Option<EmissionSample> {
        use crate::sampling::{
            square_to_cosine_hemisphere, square_to_uniform_disk_concentric, square_to_uniform_sphere,
            uniform_sphere_pdf,
        };
        let sample = match self {
            Light::Area(a) => {
                let sp = a.sample_point(u_pos);
                let n = AreaLight::emitting_normal(&sp);
                let local = square_to_cosine_hemisphere(u_dir);
                let dir = crate::geometry::Frame::from_normal(n).to_world(local);
                let le = a.emitted(&sp, dir);
                EmissionSample {
                    p: sp.p,
                    ng: n,
                    dir,
                    le,
                    pdf_pos: a.pdf_area(),
                    pdf_dir: local.z.max(0.0) * std::f32::consts::FRAC_1_PI,
                    surface: Some(sp),
                }
            }
            Light::Point(l) => EmissionSample {
                p: l.position,
                ng: Vec3::ZERO,
                dir: square_to_uniform_sphere(u_dir),
                le: l.intensity,
                pdf_pos: 1.0,
                pdf_dir: uniform_sphere_pdf(),
                surface: None,
            },
            Light::Spot(l) => {
                let (dir, pdf_dir) = l.sample_direction(u_dir);
                EmissionSample {
                    p: l.position(),
                    ng: Vec3::ZERO,
                    dir,
                    le: l.intensity * l.falloff(dir),
                    pdf_pos: 1.0,
                    pdf_dir,
                    surface: None,
                }
            }
            Light::Constant { .. } | Light::Env(_) => {
                // The direction towards the light is drawn as next-event estimation draws it, so the
                // two strategies share one density; the start point is uniform on a disk of the scene's
                // radius, perpendicular to it, just outside the bounding sphere.
                let ls = self.sample_li(centre, u_dir, scene_radius)?;
                let frame = crate::geometry::Frame::from_normal(-ls.wi);
                let d = square_to_uniform_disk_concentric(u_pos) * scene_radius;
                let p = centre + ls.wi * scene_radius + frame.to_world(Vec3::new(d.x, d.y, 0.0));
                EmissionSample {
                    p,
                    ng: Vec3::ZERO,
                    dir: -ls.wi,
                    le: ls.radiance,
                    pdf_pos: 1.0 / (PI * scene_radius * scene_radius),
                    pdf_dir: ls.pdf,
                    surface: None,
                }
            }
        };
        let valid = sample.pdf_pos > 0.0
            && sample.pdf_dir > 0.0
            && sample.pdf_dir.is_finite()
            && sample.le.is_finite()
            && sample.le.max_element() > 0.0;
        valid.then_some(sample)
    }

    /// Samples only the direction of an emitted ray from a point already on the light (emitting-side
    /// normal `n` for area lights), as `sample_le` would draw it from `u_dir`: (direction, solid-angle
    /// density, equal to `pdf_le_dir`). Path-space mutations use it to regrow a light sub-path from a
    /// kept emitter vertex. `None` for infinite lights, whose emitted rays have no fixed origin.
    pub fn sample_le_dir(&self, n: Vec3, u_dir: Vec2) -> Option<(Vec3, f32)> {
        let (dir, pdf) = match self {
            Light::Area(_) => {
                let local = crate::sampling::square_to_cosine_hemisphere(u_dir);
                let dir = crate::geometry::Frame::from_normal(n).to_world(local);
                (dir, local.z.max(0.0) * std::f32::consts::FRAC_1_PI)
            }
            Light::Point(_) => {
                (crate::sampling::square_to_uniform_sphere(u_dir), crate::sampling::uniform_sphere_pdf())
            }
            Light::Spot(l) => l.sample_direction(u_dir),
            Light::Constant { .. } | Light::Env(_) => return None,
        };
        (pdf > 0.0 && pdf.is_finite() && dir != Vec3::ZERO).then_some((dir, pdf))
    }

    /// Solid-angle density with which `sample_le` emits along `dir` from a point with emitting-side
    /// normal `n` (area lights) — for infinite lights `dir` is the direction of travel.
    pub fn pdf_le_dir(&self, n: Vec3, dir: Vec3) -> f32 {
        match self {
            Light::Area(_) => n.dot(dir).max(0.0) * std::f32::consts::FRAC_1_PI,
            Light::Point(_) => crate::sampling::uniform_sphere_pdf(),
            Light::Spot(l) => l.pdf_direction(dir),
            Light::Constant { .. } | Light::Env(_) => self.pdf_infinite(-dir),
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
