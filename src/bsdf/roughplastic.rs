//! `roughplastic`: a rough dielectric coating over a Lambertian base, as Mitsuba 3's `roughplastic`
//! plugin: microfacet specular reflection plus a diffuse term attenuated by the coating's rough
//! directional transmittance on the way in and out.
//!
//! | Parameter              | Type             | Default                | Meaning                                |
//! |------------------------|------------------|------------------------|----------------------------------------|
//! | `diffuse_reflectance`  | spectrum/texture | 0.5                    | albedo ρ of the base                   |
//! | `specular_reflectance` | spectrum/texture | 1                      | factor on the specular lobe            |
//! | `int_ior`              | float or string  | `polypropylene` (1.49) | coating index (must differ from ext)   |
//! | `ext_ior`              | float or string  | `air` (1.000277)       | exterior index                         |
//! | `nonlinear`            | boolean          | `false`                | model the colour shift of internal scattering |
//! | `distribution`         | string           | `beckmann`             | `beckmann` or `ggx`                    |
//! | `alpha`                | float            | 0.1                    | isotropic roughness (anisotropy is not supported, as in Mitsuba 3) |
//! | `sample_visible`       | boolean          | `true`                 | visible-normal sampling for the specular lobe |
//!
//! f = F D G/(4 cos θi cos θo) s + ρ' T(θi) T(θo) / (η² π), ρ' = ρ/(1 − R_int) (or ρ/(1 − ρ R_int) when
//! `nonlinear`). T(θ) is the rough-interface directional transmittance tabulated at 64 cosines and
//! R_int = 2∫R(μ)μ dμ the internal rough reflectance (relative index 1/η), both by Gauss-Legendre
//! quadrature over visible normals exactly as Mitsuba 3 precomputes them.

use super::fresnel::{fresnel_dielectric, reflect_about};
use super::microfacet::{eval_reflectance, eval_transmittance, gauss_legendre, Microfacet, MicrofacetKind};
use super::plastic::{specular_probability, specular_sampling_weight};
use super::{
    finish_sample, read_alpha, read_distribution, read_eta, sanitize, Bsdf, BsdfContext, BsdfLoader,
    BsdfLobe, BsdfSample,
};
use crate::props::{Props, SceneError};
use crate::sampling::square_to_cosine_hemisphere;
use crate::spectrum::Spectrum;
use crate::texture::Texture;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::f32::consts::FRAC_1_PI;
use std::sync::{Arc, Mutex, OnceLock};

const TRANSMITTANCE_RES: usize = 64;

/// Precomputed coating integrals for one (distribution, α, η).
#[derive(Debug)]
pub struct CoatingTables {
    /// T(μ) at μ = i/63 (the first node is clamped to 1e-6).
    pub external_transmittance: Vec<f32>,
    pub internal_reflectance: f32,
}

impl CoatingTables {
    fn compute(kind: MicrofacetKind, alpha: f32, eta: f32) -> CoatingTables {
        let distr = Microfacet::new(kind, alpha, alpha, true);
        let nodes_t = gauss_legendre(if eta > 1.0 { 32 } else { 128 });
        let nodes_r = gauss_legendre(if 1.0 / eta > 1.0 { 32 } else { 128 });
        // Each cosine is an independent 2D quadrature (up to 128² visible-normal samples): spread them.
        let rows: Vec<(f32, f64)> = (0..TRANSMITTANCE_RES)
            .into_par_iter()
            .map(|i| {
                let mu = (i as f32 / (TRANSMITTANCE_RES - 1) as f32).max(1e-6);
                let wi = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
                let t = eval_transmittance(&distr, wi, eta, &nodes_t);
                let r = eval_reflectance(&distr, wi, 1.0 / eta, &nodes_r) * mu;
                (t, r as f64)
            })
            .collect();
        let external_transmittance = rows.iter().map(|r| r.0).collect();
        let refl_sum: f64 = rows.iter().map(|r| r.1).sum();
        CoatingTables {
            external_transmittance,
            internal_reflectance: (2.0 * refl_sum / TRANSMITTANCE_RES as f64) as f32,
        }
    }

    /// Shared tables: several materials with the same coating compute them once.
    pub fn get(kind: MicrofacetKind, alpha: f32, eta: f32) -> Arc<CoatingTables> {
        type Key = (MicrofacetKind, u32, u32);
        static CACHE: OnceLock<Mutex<HashMap<Key, Arc<CoatingTables>>>> = OnceLock::new();
        let key = (kind, alpha.to_bits(), eta.to_bits());
        let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
        if let Some(t) = cache.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
            return t.clone();
        }
        let tables = Arc::new(CoatingTables::compute(kind, alpha, eta));
        cache.lock().unwrap_or_else(|e| e.into_inner()).entry(key).or_insert(tables).clone()
    }

    /// Linear interpolation in the table, as Mitsuba's `lerp_gather`.
    pub fn transmittance(&self, cos_theta: f32) -> f32 {
        let n = self.external_transmittance.len();
        let x = cos_theta.clamp(0.0, 1.0) * (n - 1) as f32;
        let index = (x as usize).min(n - 2);
        let w1 = x - index as f32;
        (1.0 - w1) * self.external_transmittance[index] + w1 * self.external_transmittance[index + 1]
    }
}

#[derive(Debug)]
pub struct RoughPlastic {
    pub distr: Microfacet,
    pub diffuse_reflectance: Texture,
    pub specular_reflectance: Option<Texture>,
    pub eta: f32,
    pub nonlinear: bool,
    inv_eta_2: f32,
    specular_sampling_weight: f32,
    tables: Arc<CoatingTables>,
}

impl RoughPlastic {
    pub fn new(
        distr: Microfacet,
        diffuse_reflectance: Texture,
        specular_reflectance: Option<Texture>,
        eta: f32,
        nonlinear: bool,
    ) -> RoughPlastic {
        let specular_sampling_weight =
            specular_sampling_weight(&diffuse_reflectance, specular_reflectance.as_ref());
        RoughPlastic {
            tables: CoatingTables::get(distr.kind, distr.alpha_u, eta),
            distr,
            diffuse_reflectance,
            specular_reflectance,
            eta,
            nonlinear,
            inv_eta_2: 1.0 / (eta * eta),
            specular_sampling_weight,
        }
    }

    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<RoughPlastic, SceneError> {
        props.expect_only(
            &[
                "diffuse_reflectance",
                "specular_reflectance",
                "int_ior",
                "ext_ior",
                "nonlinear",
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
        if au != av {
            return Err(props.error("roughplastic does not support anisotropic roughness (as Mitsuba 3)"));
        }
        let visible = props.bool("sample_visible", true)?;
        Ok(RoughPlastic::new(
            Microfacet::new(kind, au, au, visible),
            loader.texture(props, "diffuse_reflectance", Vec3::splat(0.5))?,
            loader.texture_opt(props, "specular_reflectance")?,
            read_eta(props, "polypropylene", true)?,
            props.bool("nonlinear", false)?,
        ))
    }

    pub fn internal_reflectance(&self) -> f32 {
        self.tables.internal_reflectance
    }

    fn prob_specular(&self, cos_i: f32) -> f32 {
        let t_i = self.tables.transmittance(cos_i);
        let w = self.specular_sampling_weight;
        specular_probability((1.0 - t_i) * w, t_i * (1.0 - w))
    }
}

impl Bsdf for RoughPlastic {
    fn lobes(&self) -> BsdfLobe {
        BsdfLobe::GLOSSY_REFLECTION | BsdfLobe::DIFFUSE_REFLECTION
    }

    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return Spectrum::ZERO;
        }
        let h = (wi + wo).normalize();
        let d = self.distr.d(h);
        let mut value = Spectrum::ZERO;
        if d > 0.0 {
            let f = fresnel_dielectric(wi.dot(h), self.eta).reflectance;
            let g = self.distr.g(wi, wo, h);
            let s = f * d * g / (4.0 * wi.z * wo.z);
            value += match &self.specular_reflectance {
                Some(t) => t.eval(ctx.uv) * s,
                None => Vec3::splat(s),
            };
        }
        let t_i = self.tables.transmittance(wi.z);
        let t_o = self.tables.transmittance(wo.z);
        let rho = self.diffuse_reflectance.eval(ctx.uv);
        let r_int = self.tables.internal_reflectance;
        let denom = if self.nonlinear { Vec3::ONE - rho * r_int } else { Vec3::splat(1.0 - r_int) };
        value += rho / denom * (FRAC_1_PI * self.inv_eta_2 * t_i * t_o);
        sanitize(value)
    }

    fn pdf(&self, _ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        let p_spec = self.prob_specular(wi.z);
        let spec_pdf = self.distr.reflection_pdf(wi, wo);
        let p = p_spec * spec_pdf + (1.0 - p_spec) * wo.z * FRAC_1_PI;
        if p.is_finite() {
            p
        } else {
            0.0
        }
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wi.z <= 0.0 {
            return None;
        }
        let p_spec = self.prob_specular(wi.z);
        let (wo, lobe) = if u_lobe < p_spec {
            let (m, _) = self.distr.sample(wi, u)?;
            (reflect_about(wi, m), BsdfLobe::GLOSSY_REFLECTION)
        } else {
            (square_to_cosine_hemisphere(u), BsdfLobe::DIFFUSE_REFLECTION)
        };
        if wo.z <= 0.0 {
            return None;
        }
        // Both lobes can produce every direction, so the sample carries the mixture density.
        let pdf = self.pdf(ctx, wi, wo);
        let weight = self.eval(ctx, wi, wo) * wo.z / pdf;
        finish_sample(wo, weight, pdf, lobe, 1.0)
    }

    fn roughness(&self) -> f32 {
        self.distr.alpha_u
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::fresnel::fresnel_diffuse_reflectance;

    #[test]
    fn smooth_limit_of_coating_tables() {
        // Nearly smooth coating: T(μ) → 1 − F(μ) and R_int → the smooth internal Fdr.
        let eta = 1.49f32;
        let t = CoatingTables::get(MicrofacetKind::Ggx, 0.01, eta);
        for mu in [1.0f32, 0.6, 0.3] {
            let smooth = 1.0 - fresnel_dielectric(mu, eta).reflectance;
            assert!(
                (t.transmittance(mu) - smooth).abs() < 0.01,
                "μ {mu}: {} vs {smooth}",
                t.transmittance(mu)
            );
        }
        let fdr = fresnel_diffuse_reflectance(1.0 / eta);
        assert!((t.internal_reflectance - fdr).abs() < 0.03, "{} vs {fdr}", t.internal_reflectance);
        // Transmittance is a fraction for any roughness.
        let rough = CoatingTables::get(MicrofacetKind::Beckmann, 0.5, eta);
        assert!(rough.external_transmittance.iter().all(|&x| (0.0..=1.0).contains(&x)));
        assert!(rough.internal_reflectance > 0.0 && rough.internal_reflectance < 1.0);
    }
}
