//! `plastic`: a smooth dielectric coating over a Lambertian base, with internal scattering between
//! them, as Mitsuba 3's `plastic` plugin (after Weidlich & Wilkie 2007 and Mitsuba 0.6).
//!
//! | Parameter              | Type             | Default                   | Meaning                                 |
//! |------------------------|------------------|---------------------------|-----------------------------------------|
//! | `diffuse_reflectance`  | spectrum/texture | 0.5                       | albedo ρ of the base                    |
//! | `specular_reflectance` | spectrum/texture | 1                         | factor on the coating's mirror lobe     |
//! | `int_ior`              | float or string  | `polypropylene` (1.49)    | coating index                           |
//! | `ext_ior`              | float or string  | `air` (1.000277)          | exterior index                          |
//! | `nonlinear`            | boolean          | `false`                   | model the colour shift of internal scattering |
//!
//! Delta lobe: F(cos θi) × specular_reflectance in the mirror direction. Diffuse lobe:
//! f = ρ' (1−F(cos θi))(1−F(cos θo)) / (η² π) with ρ' = ρ/(1 − Fdr_int) (or ρ/(1 − ρ Fdr_int) when
//! `nonlinear`), Fdr_int = hemispherical Fresnel reflectance seen from inside (relative index 1/η).
//! The lobe is picked with probability ∝ F·s̄ vs (1−F)(1−s̄), s̄ = mean specular / (mean diffuse + mean specular).

use super::fresnel::{fresnel_dielectric, fresnel_diffuse_reflectance, reflect_local};
use super::{finish_sample, read_eta, sanitize, Bsdf, BsdfContext, BsdfLoader, BsdfLobe, BsdfSample};
use crate::props::{Props, SceneError};
use crate::sampling::square_to_cosine_hemisphere;
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

#[derive(Debug)]
pub struct SmoothPlastic {
    pub diffuse_reflectance: Texture,
    pub specular_reflectance: Option<Texture>,
    pub eta: f32,
    pub nonlinear: bool,
    inv_eta_2: f32,
    fdr_int: f32,
    specular_sampling_weight: f32,
}

/// Mitsuba's lobe-selection weight s̄ / (d̄ + s̄), guarded against black materials.
pub(crate) fn specular_sampling_weight(diffuse: &Texture, specular: Option<&Texture>) -> f32 {
    let d = diffuse.mean_scalar().max(0.0);
    let s = specular.map_or(1.0, |t| t.mean_scalar().max(0.0));
    if d + s > 0.0 {
        s / (d + s)
    } else {
        0.5
    }
}

/// Probability of picking the specular lobe given the weights of both.
pub(crate) fn specular_probability(spec: f32, diff: f32) -> f32 {
    if spec + diff > 0.0 && (spec + diff).is_finite() {
        spec / (spec + diff)
    } else {
        0.5
    }
}

impl SmoothPlastic {
    pub fn new(
        diffuse_reflectance: Texture,
        specular_reflectance: Option<Texture>,
        eta: f32,
        nonlinear: bool,
    ) -> SmoothPlastic {
        let specular_sampling_weight =
            specular_sampling_weight(&diffuse_reflectance, specular_reflectance.as_ref());
        SmoothPlastic {
            diffuse_reflectance,
            specular_reflectance,
            eta,
            nonlinear,
            inv_eta_2: 1.0 / (eta * eta),
            fdr_int: fresnel_diffuse_reflectance(1.0 / eta),
            specular_sampling_weight,
        }
    }

    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<SmoothPlastic, SceneError> {
        props.expect_only(
            &["diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear"],
            &[],
        )?;
        Ok(SmoothPlastic::new(
            loader.texture(props, "diffuse_reflectance", Vec3::splat(0.5))?,
            loader.texture_opt(props, "specular_reflectance")?,
            read_eta(props, "polypropylene", false)?,
            props.bool("nonlinear", false)?,
        ))
    }

    fn prob_specular(&self, f_i: f32) -> f32 {
        let w = self.specular_sampling_weight;
        specular_probability(f_i * w, (1.0 - f_i) * (1.0 - w))
    }

    fn diffuse_term(&self, ctx: &BsdfContext, f_i: f32, cos_o: f32) -> Spectrum {
        let f_o = fresnel_dielectric(cos_o, self.eta).reflectance;
        let rho = self.diffuse_reflectance.eval(ctx.uv);
        let denom =
            if self.nonlinear { Vec3::ONE - rho * self.fdr_int } else { Vec3::splat(1.0 - self.fdr_int) };
        sanitize(rho / denom * (self.inv_eta_2 * (1.0 - f_i) * (1.0 - f_o) * FRAC_1_PI))
    }
}

impl Bsdf for SmoothPlastic {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::DELTA_REFLECTION | BsdfLobe::DIFFUSE_REFLECTION
    }

    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return Spectrum::ZERO;
        }
        let f_i = fresnel_dielectric(wi.z, self.eta).reflectance;
        self.diffuse_term(ctx, f_i, wo.z)
    }

    fn pdf(&self, _ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        let f_i = fresnel_dielectric(wi.z, self.eta).reflectance;
        (1.0 - self.prob_specular(f_i)) * wo.z * FRAC_1_PI
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wi.z <= 0.0 {
            return None;
        }
        let f_i = fresnel_dielectric(wi.z, self.eta).reflectance;
        let p_spec = self.prob_specular(f_i);
        if u_lobe < p_spec {
            let tint = match &self.specular_reflectance {
                Some(t) => t.eval(ctx.uv),
                None => Vec3::ONE,
            };
            finish_sample(reflect_local(wi), tint * (f_i / p_spec), p_spec, BsdfLobe::DELTA_REFLECTION, 1.0)
        } else {
            let wo = square_to_cosine_hemisphere(u);
            if wo.z <= 0.0 {
                return None;
            }
            let pdf = (1.0 - p_spec) * wo.z * FRAC_1_PI;
            let weight = self.diffuse_term(ctx, f_i, wo.z) * wo.z / pdf;
            finish_sample(wo, weight, pdf, BsdfLobe::DIFFUSE_REFLECTION, 1.0)
        }
    }

    fn roughness(&self) -> f32 {
        0.0
    }
}
