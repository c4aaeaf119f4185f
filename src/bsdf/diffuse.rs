//! `diffuse`: the ideal Lambertian reflector, one-sided, as Mitsuba 3's `diffuse` plugin.
//!
//! | Parameter     | Type             | Default | Meaning                        |
//! |---------------|------------------|---------|--------------------------------|
//! | `reflectance` | spectrum/texture | 0.5     | albedo ρ; f = ρ/π on the front |
//!
//! Light arriving from or leaving towards the back (cos θ ≤ 0) is not scattered; wrap it in `twosided`
//! for two-sided surfaces. Sampling is cosine-weighted, so the weight is exactly ρ.

use super::{finish_sample, sanitize, Bsdf, BsdfContext, BsdfLoader, BsdfLobe, BsdfSample};
use crate::props::{Props, SceneError};
use crate::sampling::square_to_cosine_hemisphere;
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

#[derive(Debug)]
pub struct Diffuse {
    pub reflectance: Texture,
}

impl Diffuse {
    pub fn new(reflectance: Texture) -> Diffuse {
        Diffuse { reflectance }
    }

    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<Diffuse, SceneError> {
        props.expect_only(&["reflectance"], &[])?;
        Ok(Diffuse::new(loader.texture(props, "reflectance", Vec3::splat(0.5))?))
    }
}

impl Bsdf for Diffuse {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::DIFFUSE_REFLECTION
    }

    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return Spectrum::ZERO;
        }
        sanitize(self.reflectance.eval(ctx.uv) * FRAC_1_PI)
    }

    fn pdf(&self, _ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        wo.z * FRAC_1_PI
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, _u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wi.z <= 0.0 {
            return None;
        }
        let wo = square_to_cosine_hemisphere(u);
        if wo.z <= 0.0 {
            return None;
        }
        let weight = sanitize(self.reflectance.eval(ctx.uv));
        finish_sample(wo, weight, wo.z * FRAC_1_PI, BsdfLobe::DIFFUSE_REFLECTION, 1.0)
    }

    fn roughness(&self) -> f32 {
        f32::INFINITY
    }
}
