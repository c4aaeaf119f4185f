//! `dielectric`: a perfectly smooth interface between two dielectrics (Dirac reflection and
//! refraction chosen in proportion to the Fresnel reflectance), as Mitsuba 3's `dielectric` plugin.
//!
//! | Parameter                | Type             | Default          | Meaning                                   |
//! |--------------------------|------------------|------------------|-------------------------------------------|
//! | `int_ior`                | float or string  | `bk7` (1.5046)   | interior index, numerically or by name    |
//! | `ext_ior`                | float or string  | `air` (1.000277) | exterior index (the side the normal faces)|
//! | `specular_reflectance`   | spectrum/texture | 1                | factor on reflection (unphysical)         |
//! | `specular_transmittance` | spectrum/texture | 1                | factor on transmission (unphysical)       |
//!
//! Refraction in radiance mode carries the (η_i/η_t)² solid-angle compression factor; importance mode
//! does not (Veach 1997, §5.2), so that the two modes are adjoint.

use super::fresnel::{fresnel_dielectric, reflect_local};
use super::{finish_sample, read_eta, Bsdf, BsdfContext, BsdfLoader, BsdfLobe, BsdfSample, TransportMode};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};

#[derive(Debug)]
pub struct SmoothDielectric {
    /// int_ior / ext_ior.
    pub eta: f32,
    pub specular_reflectance: Option<Texture>,
    pub specular_transmittance: Option<Texture>,
}

impl SmoothDielectric {
    pub fn new(eta: f32) -> SmoothDielectric {
        SmoothDielectric { eta, specular_reflectance: None, specular_transmittance: None }
    }

    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<SmoothDielectric, SceneError> {
        props.expect_only(&["int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"], &[])?;
        Ok(SmoothDielectric {
            eta: read_eta(props, "bk7", false)?,
            specular_reflectance: loader.texture_opt(props, "specular_reflectance")?,
            specular_transmittance: loader.texture_opt(props, "specular_transmittance")?,
        })
    }
}

impl Bsdf for SmoothDielectric {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::DELTA_REFLECTION | BsdfLobe::DELTA_TRANSMISSION
    }

    fn eval(&self, _ctx: &BsdfContext, _wi: Vec3, _wo: Vec3) -> Spectrum {
        Spectrum::ZERO
    }

    fn pdf(&self, _ctx: &BsdfContext, _wi: Vec3, _wo: Vec3) -> f32 {
        0.0
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, u_lobe: f32, _u: Vec2) -> Option<BsdfSample> {
        if !wi.is_finite() {
            return None;
        }
        let fr = fresnel_dielectric(wi.z, self.eta);
        let r = fr.reflectance;
        if u_lobe <= r {
            let weight = match &self.specular_reflectance {
                Some(t) => t.eval(ctx.uv),
                None => Vec3::ONE,
            };
            finish_sample(reflect_local(wi), weight, r, BsdfLobe::DELTA_REFLECTION, 1.0)
        } else {
            let wo = Vec3::new(-fr.eta_ti * wi.x, -fr.eta_ti * wi.y, fr.cos_theta_t);
            if wo.z * wi.z >= 0.0 {
                return None;
            }
            let mut weight = match &self.specular_transmittance {
                Some(t) => t.eval(ctx.uv),
                None => Vec3::ONE,
            };
            if ctx.mode == TransportMode::Radiance {
                weight *= fr.eta_ti * fr.eta_ti;
            }
            finish_sample(wo, weight, 1.0 - r, BsdfLobe::DELTA_TRANSMISSION, fr.eta_it)
        }
    }

    fn roughness(&self) -> f32 {
        0.0
    }

    fn eta(&self) -> f32 {
        self.eta
    }
}
