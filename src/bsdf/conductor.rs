//! `conductor`: a perfectly smooth metal (a Dirac mirror weighted by the conductor Fresnel term),
//! one-sided, as Mitsuba 3's `conductor` plugin.
//!
//! | Parameter              | Type             | Default  | Meaning                                          |
//! |------------------------|------------------|----------|--------------------------------------------------|
//! | `material`             | string           | `none`   | preset: `none` (100% mirror), `Au`, `Ag`, `Cu`, `Al`, `Cr`, `W`, … (see `ior.rs`) |
//! | `eta`, `k`             | spectrum/texture | 0, 1     | explicit complex index η + ik (instead of `material`) |
//! | `specular_reflectance` | spectrum/texture | 1        | factor on the reflection (unphysical; leave at 1) |
//!
//! Reflectance is the exact unpolarised conductor Fresnel formula evaluated per RGB channel.

use super::fresnel::{fresnel_conductor, reflect_local};
use super::{finish_sample, read_conductor_ior, Bsdf, BsdfContext, BsdfLoader, BsdfLobe, BsdfSample};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};

#[derive(Debug)]
pub struct SmoothConductor {
    pub eta: Texture,
    pub k: Texture,
    pub specular_reflectance: Texture,
}

impl SmoothConductor {
    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<SmoothConductor, SceneError> {
        props.expect_only(&["material", "eta", "k", "specular_reflectance"], &[])?;
        let (eta, k) = read_conductor_ior(props, loader)?;
        Ok(SmoothConductor {
            eta,
            k,
            specular_reflectance: loader.texture(props, "specular_reflectance", Vec3::ONE)?,
        })
    }
}

impl Bsdf for SmoothConductor {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::DELTA_REFLECTION
    }

    fn eval(&self, _ctx: &BsdfContext, _wi: Vec3, _wo: Vec3) -> Spectrum {
        Spectrum::ZERO
    }

    fn pdf(&self, _ctx: &BsdfContext, _wi: Vec3, _wo: Vec3) -> f32 {
        0.0
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, _u_lobe: f32, _u: Vec2) -> Option<BsdfSample> {
        if wi.z <= 0.0 {
            return None;
        }
        let f = fresnel_conductor(wi.z, self.eta.eval(ctx.uv), self.k.eval(ctx.uv));
        let weight = f * self.specular_reflectance.eval(ctx.uv);
        finish_sample(reflect_local(wi), weight, 1.0, BsdfLobe::DELTA_REFLECTION, 1.0)
    }

    fn roughness(&self) -> f32 {
        0.0
    }
}
