//! `roughdielectric`: a rough interface between two dielectrics, Walter et al. 2007 microfacet
//! reflection and refraction, as Mitsuba 3's `roughdielectric` plugin.
//!
//! | Parameter                | Type             | Default          | Meaning                                     |
//! |--------------------------|------------------|------------------|---------------------------------------------|
//! | `int_ior`                | float or string  | `bk7` (1.5046)   | interior index (must differ from exterior)  |
//! | `ext_ior`                | float or string  | `air` (1.000277) | exterior index                              |
//! | `specular_reflectance`   | spectrum/texture | 1                | factor on reflection                        |
//! | `specular_transmittance` | spectrum/texture | 1                | factor on transmission                      |
//! | `distribution`           | string           | `beckmann`       | `beckmann` or `ggx`                         |
//! | `alpha`                  | float            | 0.1              | isotropic roughness                         |
//! | `alpha_u`, `alpha_v`     | float            | —                | anisotropic roughness                       |
//! | `sample_visible`         | boolean          | `true`           | visible-normal sampling; when false, all normals with Walter's (1.2 − 0.2√|cos θi|) roughness widening |
//!
//! Transmission: f = |wi·m||wo·m| η² (1−F) D G / (|cos θi||cos θo| (wi·m + η wo·m)²) in importance mode,
//! times 1/η² in radiance mode (η = η_o/η_i for this crossing), which makes f_importance(wi, wo) equal
//! f_radiance(wo, wi) (Veach 1997, §5.2). With `sample_visible=false` the sample weight is computed as
//! f|cos θo|/pdf with the widened pdf (Mitsuba 3 reuses the unwidened weight formula there).

use super::fresnel::{fresnel_dielectric, reflect_about, refract_about};
use super::microfacet::Microfacet;
use super::{
    finish_sample, read_alpha, read_distribution, read_eta, sanitize, Bsdf, BsdfContext, BsdfLoader,
    BsdfLobe, BsdfSample, TransportMode,
};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};

#[derive(Debug)]
pub struct RoughDielectric {
    pub distr: Microfacet,
    /// int_ior / ext_ior.
    pub eta: f32,
    pub specular_reflectance: Option<Texture>,
    pub specular_transmittance: Option<Texture>,
}

impl RoughDielectric {
    pub fn new(distr: Microfacet, eta: f32) -> RoughDielectric {
        RoughDielectric { distr, eta, specular_reflectance: None, specular_transmittance: None }
    }

    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<RoughDielectric, SceneError> {
        props.expect_only(
            &[
                "int_ior",
                "ext_ior",
                "specular_reflectance",
                "specular_transmittance",
                "distribution",
                "alpha",
                "alpha_u",
                "alpha_v",
                "sample_visible",
            ],
            &[],
        )?;
        let kind = read_distribution(props)?;
        let (au, av) = read_alpha(props)?;
        let visible = props.bool("sample_visible", true)?;
        Ok(RoughDielectric {
            distr: Microfacet::new(kind, au, av, visible),
            eta: read_eta(props, "bk7", true)?,
            specular_reflectance: loader.texture_opt(props, "specular_reflectance")?,
            specular_transmittance: loader.texture_opt(props, "specular_transmittance")?,
        })
    }

    /// The distribution `sample`/`pdf` draw from for incidence cosine `cos_i`.
    fn sampling_distr(&self, cos_i: f32) -> Microfacet {
        if self.distr.sample_visible {
            self.distr
        } else {
            self.distr.scaled(1.2 - 0.2 * cos_i.abs().sqrt())
        }
    }

    /// Relative index η_o/η_i as seen from the side of `wi`.
    fn eta_from(&self, cos_i: f32) -> f32 {
        if cos_i > 0.0 {
            self.eta
        } else {
            1.0 / self.eta
        }
    }

    /// The generalized half vector of (wi, wo), oriented to the macro-surface normal.
    fn half_vector(&self, wi: Vec3, wo: Vec3) -> Option<(Vec3, bool, f32)> {
        let reflect = wi.z * wo.z > 0.0;
        let eta = self.eta_from(wi.z);
        let h = wi + wo * if reflect { 1.0 } else { eta };
        let len2 = h.length_squared();
        if !(len2 > 1e-12 && len2.is_finite()) {
            return None;
        }
        let m = h / len2.sqrt();
        Some((if m.z < 0.0 { -m } else { m }, reflect, eta))
    }

    fn tint(t: &Option<Texture>, ctx: &BsdfContext) -> Spectrum {
        match t {
            Some(t) => t.eval(ctx.uv),
            None => Vec3::ONE,
        }
    }
}

impl Bsdf for RoughDielectric {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::GLOSSY_REFLECTION | BsdfLobe::GLOSSY_TRANSMISSION
    }

    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum {
        let (cos_i, cos_o) = (wi.z, wo.z);
        if cos_i == 0.0 || cos_o == 0.0 {
            return Spectrum::ZERO;
        }
        let Some((m, reflect, eta)) = self.half_vector(wi, wo) else {
            return Spectrum::ZERO;
        };
        let d = self.distr.d(m);
        if d == 0.0 {
            return Spectrum::ZERO;
        }
        let g = self.distr.g(wi, wo, m);
        if g == 0.0 {
            return Spectrum::ZERO;
        }
        let (wi_m, wo_m) = (wi.dot(m), wo.dot(m));
        let f = fresnel_dielectric(wi_m, self.eta).reflectance;
        if reflect {
            let v = f * d * g / (4.0 * cos_i.abs() * cos_o.abs());
            sanitize(Self::tint(&self.specular_reflectance, ctx) * v)
        } else {
            let scale = match ctx.mode {
                TransportMode::Radiance => 1.0 / (eta * eta),
                TransportMode::Importance => 1.0,
            };
            let denom = wi_m + eta * wo_m;
            let v =
                (scale * (1.0 - f) * d * g * eta * eta * wi_m * wo_m / (cos_i * cos_o * denom * denom)).abs();
            sanitize(Self::tint(&self.specular_transmittance, ctx) * v)
        }
    }

    fn pdf(&self, _ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32 {
        let (cos_i, cos_o) = (wi.z, wo.z);
        if cos_i == 0.0 || cos_o == 0.0 {
            return 0.0;
        }
        let Some((m, reflect, eta)) = self.half_vector(wi, wo) else {
            return 0.0;
        };
        let (wi_m, wo_m) = (wi.dot(m), wo.dot(m));
        // Microfacets seen from the wrong side contribute nothing to eval or sample.
        if wi_m * cos_i <= 0.0 || wo_m * cos_o <= 0.0 {
            return 0.0;
        }
        let dwh_dwo = if reflect {
            1.0 / (4.0 * wo_m)
        } else {
            let denom = wi_m + eta * wo_m;
            eta * eta * wo_m / (denom * denom)
        };
        let distr = self.sampling_distr(cos_i);
        let wi_up = if cos_i > 0.0 { wi } else { -wi };
        let mut p = distr.pdf(wi_up, m);
        let f = fresnel_dielectric(wi_m, self.eta).reflectance;
        p *= if reflect { f } else { 1.0 - f };
        let p = p * dwh_dwo.abs();
        if p.is_finite() {
            p
        } else {
            0.0
        }
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        let cos_i = wi.z;
        if cos_i == 0.0 || !wi.is_finite() {
            return None;
        }
        let distr = self.sampling_distr(cos_i);
        let wi_up = if cos_i > 0.0 { wi } else { -wi };
        let (m, pdf_m) = distr.sample(wi_up, u)?;
        let wi_m = wi.dot(m);
        if wi_m * cos_i <= 0.0 {
            return None;
        }
        let fr = fresnel_dielectric(wi_m, self.eta);
        let f = fr.reflectance;
        let (wo, pdf, lobe, eta, mut weight) = if u_lobe <= f {
            let wo = reflect_about(wi, m);
            if wo.z * cos_i <= 0.0 {
                return None;
            }
            let pdf = pdf_m * f / (4.0 * wo.dot(m).abs());
            let tint = Self::tint(&self.specular_reflectance, ctx);
            (wo, pdf, BsdfLobe::GLOSSY_REFLECTION, 1.0, tint)
        } else {
            let wo = refract_about(wi, m, fr.cos_theta_t, fr.eta_ti);
            if wo.z * cos_i >= 0.0 {
                return None;
            }
            let wo_m = wo.dot(m);
            let denom = wi_m + fr.eta_it * wo_m;
            let dwh_dwo = fr.eta_it * fr.eta_it * wo_m / (denom * denom);
            let pdf = pdf_m * (1.0 - f) * dwh_dwo.abs();
            let mut tint = Self::tint(&self.specular_transmittance, ctx);
            if ctx.mode == TransportMode::Radiance {
                tint *= fr.eta_ti * fr.eta_ti;
            }
            (wo, pdf, BsdfLobe::GLOSSY_TRANSMISSION, fr.eta_it, tint)
        };
        if self.distr.sample_visible {
            weight *= self.distr.g1(wo, m);
        } else {
            // The widened sampling density does not cancel D: use the generic estimator.
            let pdf_full = self.pdf(ctx, wi, wo);
            if pdf_full <= 0.0 || pdf_full.is_nan() {
                return None;
            }
            weight = self.eval(ctx, wi, wo) * wo.z.abs() / pdf_full;
            return finish_sample(wo, weight, pdf_full, lobe, eta);
        }
        finish_sample(wo, weight, pdf, lobe, eta)
    }

    fn roughness(&self) -> f32 {
        self.distr.alpha_u.min(self.distr.alpha_v)
    }

    fn eta(&self) -> f32 {
        self.eta
    }
}
