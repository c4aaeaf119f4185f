//! `roughconductor`: a rough metal, Cook-Torrance/Walter microfacet reflection with the conductor
//! Fresnel term, one-sided, as Mitsuba 3's `roughconductor` plugin.
//!
//! | Parameter              | Type             | Default    | Meaning                                        |
//! |------------------------|------------------|------------|------------------------------------------------|
//! | `material`             | string           | `none`     | conductor preset (see `conductor`)             |
//! | `eta`, `k`             | spectrum/texture | 0, 1       | explicit complex index η + ik                  |
//! | `specular_reflectance` | spectrum/texture | 1          | factor on the reflection                       |
//! | `distribution`         | string           | `beckmann` | `beckmann` or `ggx`                            |
//! | `alpha`                | float            | 0.1        | isotropic roughness (RMS slope for Beckmann)    |
//! | `alpha_u`, `alpha_v`   | float            | —          | anisotropic roughness along the tangents        |
//! | `sample_visible`       | boolean          | `true`     | sample visible normals (Heitz & d'Eon 2014)     |
//!
//! f(wi, wo) = F(wi·h) D(h) G(wi, wo, h) / (4 cos θi cos θo), h = normalize(wi + wo).

use super::fresnel::{fresnel_conductor, reflect_about};
use super::microfacet::Microfacet;
use super::{
    finish_sample, read_alpha, read_conductor_ior, read_distribution, sanitize, Bsdf, BsdfContext,
    BsdfLoader, BsdfLobe, BsdfSample,
};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};

#[derive(Debug)]
pub struct RoughConductor {
    pub distr: Microfacet,
    pub eta: Texture,
    pub k: Texture,
    pub specular_reflectance: Texture,
}

impl RoughConductor {
    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<RoughConductor, SceneError> {
        props.expect_only(
            &[
                "material",
                "eta",
                "k",
                "specular_reflectance",
                "distribution",
                "alpha",
                "alpha_u",
                "alpha_v",
                "sample_visible",
            ],
            &[],
        )?;
        let (eta, k) = read_conductor_ior(props, loader)?;
        let kind = read_distribution(props)?;
        let (au, av) = read_alpha(props)?;
        let visible = props.bool("sample_visible", true)?;
        Ok(RoughConductor {
            distr: Microfacet::new(kind, au, av, visible),
            eta,
            k,
            specular_reflectance: loader.texture(props, "specular_reflectance", Vec3::ONE)?,
        })
    }

    fn fresnel(&self, ctx: &BsdfContext, cos: f32) -> Spectrum {
        fresnel_conductor(cos, self.eta.eval(ctx.uv), self.k.eval(ctx.uv))
            * self.specular_reflectance.eval(ctx.uv)
    }
}

impl Bsdf for RoughConductor {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::GLOSSY_REFLECTION
    }

    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return Spectrum::ZERO;
        }
        let h = (wi + wo).normalize();
        let d = self.distr.d(h);
        if d == 0.0 {
            return Spectrum::ZERO;
        }
        let g = self.distr.g(wi, wo, h);
        let scalar = d * g / (4.0 * wi.z * wo.z);
        sanitize(self.fresnel(ctx, wi.dot(h)) * scalar)
    }

    fn pdf(&self, _ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32 {
        self.distr.reflection_pdf(wi, wo)
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, _u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wi.z <= 0.0 {
            return None;
        }
        let (m, pdf_m) = self.distr.sample(wi, u)?;
        let wo = reflect_about(wi, m);
        let wo_m = wo.dot(m);
        if wo.z <= 0.0 || wo_m <= 0.0 {
            return None;
        }
        let pdf = pdf_m / (4.0 * wo_m);
        let weight = if self.distr.sample_visible {
            self.fresnel(ctx, wi.dot(m)) * self.distr.g1(wo, m)
        } else {
            self.eval(ctx, wi, wo) * wo.z / pdf
        };
        finish_sample(wo, weight, pdf, BsdfLobe::GLOSSY_REFLECTION, 1.0)
    }

    fn roughness(&self) -> f32 {
        self.distr.alpha_u.min(self.distr.alpha_v)
    }
}
