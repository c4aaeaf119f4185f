//! Fresnel equations for the BSDFs: exact unpolarised dielectric reflectance (with total internal
//! reflection), the exact conductor formula for a complex index η + ik (Moeller, "Optics", 1988, as
//! Mitsuba 3's `fresnel_conductor`), and the fitted hemispherical average ("Fdr") used by `plastic`.

use crate::spectrum::Spectrum;
use glam::Vec3;

/// Result of the dielectric Fresnel equations for one incident cosine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DielectricFresnel {
    /// Unpolarised reflectance (1 under total internal reflection).
    pub reflectance: f32,
    /// Signed cosine of the transmitted direction: opposite sign to the incident cosine; 0 under TIR.
    pub cos_theta_t: f32,
    /// Relative index η_t/η_i in the direction of travel.
    pub eta_it: f32,
    /// Its reciprocal η_i/η_t, which also scales the tangential components of the refracted vector.
    pub eta_ti: f32,
}

/// Dielectric Fresnel reflectance for an interface whose relative index is `eta` = η_inside/η_outside,
/// the outside being the side the normal points into (`cos_theta_i` > 0 means incidence from outside).
pub fn fresnel_dielectric(cos_theta_i: f32, eta: f32) -> DielectricFresnel {
    let outside = cos_theta_i >= 0.0;
    let (eta_it, eta_ti) = if outside {
        (eta, 1.0 / eta)
    } else {
        (1.0 / eta, eta)
    };
    let cos_i = cos_theta_i.abs().min(1.0);
    let cos_t_sqr = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti;
    if eta == 1.0 {
        return DielectricFresnel {
            reflectance: 0.0,
            cos_theta_t: -cos_theta_i,
            eta_it,
            eta_ti,
        };
    }
    if cos_t_sqr <= 0.0 || cos_i == 0.0 {
        // Total internal reflection, or exactly grazing incidence where everything reflects.
        return DielectricFresnel {
            reflectance: 1.0,
            cos_theta_t: 0.0,
            eta_it,
            eta_ti,
        };
    }
    let cos_t = cos_t_sqr.sqrt();
    let a_s = (cos_i - eta_it * cos_t) / (cos_i + eta_it * cos_t);
    let a_p = (cos_t - eta_it * cos_i) / (cos_t + eta_it * cos_i);
    let reflectance = (0.5 * (a_s * a_s + a_p * a_p)).clamp(0.0, 1.0);
    DielectricFresnel {
        reflectance,
        cos_theta_t: if outside { -cos_t } else { cos_t },
        eta_it,
        eta_ti,
    }
}

/// Unpolarised reflectance of a conductor with complex relative index `eta + i k`, per channel.
/// Assumes incidence from outside the metal (`cos_theta_i` is taken by absolute value).
pub fn fresnel_conductor(cos_theta_i: f32, eta: Spectrum, k: Spectrum) -> Spectrum {
    let c = cos_theta_i.abs().min(1.0);
    Vec3::new(
        fresnel_conductor_1(c, eta.x, k.x),
        fresnel_conductor_1(c, eta.y, k.y),
        fresnel_conductor_1(c, eta.z, k.z),
    )
}

fn fresnel_conductor_1(cos_i: f32, eta: f32, k: f32) -> f32 {
    // Evaluated in f64: for large k and grazing angles the two terms nearly cancel.
    let cos_i = cos_i as f64;
    let (eta, k) = (eta as f64, k as f64);
    let cos2 = cos_i * cos_i;
    let sin2 = 1.0 - cos2;
    let sin4 = sin2 * sin2;
    let t1 = eta * eta - k * k - sin2;
    let a2pb2 = (t1 * t1 + 4.0 * k * k * eta * eta).max(0.0).sqrt();
    let a = (0.5 * (a2pb2 + t1)).max(0.0).sqrt();
    let term1 = a2pb2 + cos2;
    let term2 = 2.0 * cos_i * a;
    let denom_s = term1 + term2;
    let r_s = if denom_s > 0.0 {
        (term1 - term2) / denom_s
    } else {
        1.0
    };
    let term3 = a2pb2 * cos2 + sin4;
    let term4 = term2 * sin2;
    let denom_p = term3 + term4;
    let r_p = if denom_p > 0.0 {
        r_s * (term3 - term4) / denom_p
    } else {
        r_s
    };
    let r = 0.5 * (r_s + r_p);
    if r.is_finite() {
        r.clamp(0.0, 1.0) as f32
    } else {
        1.0
    }
}

/// Hemispherical average of the dielectric Fresnel reflectance ("Fdr") for relative index `eta`,
/// using the same fits as Mitsuba 3: Egan & Hilgeman (1973) below 1, d'Eon & Irving (2011) above.
pub fn fresnel_diffuse_reflectance(eta: f32) -> f32 {
    if eta < 1.0 {
        -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    } else {
        let x = 1.0 / eta;
        0.919317 + x * (-3.4793 + x * (6.75335 + x * (-7.80989 + x * (4.98554 + x * -1.36881))))
    }
}

/// Mirror reflection about the local normal +z.
pub fn reflect_local(wi: Vec3) -> Vec3 {
    Vec3::new(-wi.x, -wi.y, wi.z)
}

/// Mirror reflection about a microfacet normal `m`.
pub fn reflect_about(wi: Vec3, m: Vec3) -> Vec3 {
    2.0 * wi.dot(m) * m - wi
}

/// Refraction about a microfacet normal `m`, given `cos_theta_t` and `eta_ti` from
/// [`fresnel_dielectric`] evaluated at `wi·m`.
pub fn refract_about(wi: Vec3, m: Vec3, cos_theta_t: f32, eta_ti: f32) -> Vec3 {
    m * (wi.dot(m) * eta_ti + cos_theta_t) - wi * eta_ti
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_normal_incidence_and_tir() {
        let f = fresnel_dielectric(1.0, 1.5);
        let expected = ((1.5f32 - 1.0) / 2.5).powi(2);
        assert!((f.reflectance - expected).abs() < 1e-6);
        assert!((f.cos_theta_t + 1.0).abs() < 1e-6);
        // From inside at 60°, sin_t = 1.5 * 0.866 > 1: total internal reflection.
        let f = fresnel_dielectric(-0.5, 1.5);
        assert_eq!(f.reflectance, 1.0);
        assert_eq!(f.eta_it, 1.0 / 1.5);
        // Fresnel reflectance is the same for the two directions of a refracted pair.
        let a = fresnel_dielectric(0.7, 1.33);
        let b = fresnel_dielectric(a.cos_theta_t, 1.33);
        assert!((a.reflectance - b.reflectance).abs() < 1e-5);
    }

    #[test]
    fn conductor_limits() {
        // k = 0 reduces to the dielectric formula.
        let c = fresnel_conductor(0.6, Vec3::splat(1.5), Vec3::ZERO);
        let d = fresnel_dielectric(0.6, 1.5).reflectance;
        assert!((c.x - d).abs() < 1e-5, "{c} vs {d}");
        // Mitsuba's "none" material (eta 0, k 1) is a perfect mirror.
        let m = fresnel_conductor(0.3, Vec3::ZERO, Vec3::ONE);
        assert!((m - Vec3::ONE).abs().max_element() < 1e-6);
        // Grazing incidence reflects everything.
        let g = fresnel_conductor(0.0, Vec3::new(0.2, 0.9, 1.1), Vec3::new(3.9, 2.4, 2.1));
        assert!((g - Vec3::ONE).abs().max_element() < 1e-5);
    }

    #[test]
    fn fdr_matches_numerical_average() {
        for eta in [0.6f32, 1.0 / 1.5, 1.33, 1.5, 2.0] {
            // Fdr = 2 ∫ F(μ) μ dμ.
            let n = 20000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let mu = (i as f64 + 0.5) / n as f64;
                sum += fresnel_dielectric(mu as f32, eta).reflectance as f64 * mu;
            }
            let numeric = 2.0 * sum / n as f64;
            let fit = fresnel_diffuse_reflectance(eta) as f64;
            assert!(
                (numeric - fit).abs() < 0.01,
                "eta {eta}: {numeric} vs {fit}"
            );
        }
    }
}
