//! Scattering with a prescribed half vector, and the change of measure at a Dirac vertex between
//! solid angle and half-vector coordinates (Jakob and Marschner 2012, Sec. 4; Walter et al. 2007 for
//! refraction). Manifold perturbations trace a chain from a moved vertex while every specular (or
//! treated-as-specular) vertex keeps its projected half vector h⊥ in its own shading frame.

use glam::{DVec2, DVec3};

use super::constraint::{half_vector, LocalGeometry};
use crate::path::Vertex;

/// How far the recomputed half vector of a constructed direction may sit from the requested one: the
/// inversion is closed-form, so anything beyond rounding means a wrong branch (sign or side).
const INVERSION_TOLERANCE: f64 = 1e-7;

/// The unit direction `wo` leaving `cur` such that the generalised half vector of (wi, wo) projects to
/// `h` in `cur`'s shading frame (the constraint of `constraint::half_vector`, whose orientation and
/// relative-index rules it inverts). `wi` is the unit direction towards the previous vertex;
/// `transmit` selects refraction through the surface (relative index `eta`, the BSDF's
/// interior/exterior ratio) instead of reflection. At an index-matched interface the constraint is
/// the unnormalised h = P_st(wi + wo), inverted as such. `None` for total internal reflection, |h| ≥ 1
/// (normalised forms), or a result on the wrong side of the geometric surface.
pub fn scatter_with_half_vector(
    cur: &LocalGeometry,
    wi: DVec3,
    h: DVec2,
    eta: f64,
    transmit: bool,
) -> Option<DVec3> {
    let (s, t) = cur.shading_frame()?;
    let cos_i = cur.ng.dot(wi);
    let eta_rel = if cos_i > 0.0 { eta } else { 1.0 / eta };
    let wo = if transmit && (eta_rel - 1.0).abs() < 1e-9 {
        // Unnormalised: H~ = a + z n with a = s h.x + t h.y and wo = H~ − wi; |wo| = 1 gives
        // z² − 2 (n·wi) z + |a|² − 2 a·wi = 0. The root near z = 0 (wo ≈ −wi) goes straight through;
        // the other one is the mirror direction.
        let a = s * h.x + t * h.y;
        let b = cur.n.dot(wi);
        let disc = b * b - a.length_squared() + 2.0 * a.dot(wi);
        if !(disc >= 0.0) {
            return None;
        }
        a + cur.n * (b - disc.sqrt().copysign(b)) - wi
    } else {
        let z2 = 1.0 - h.length_squared();
        if !(z2 > 0.0) {
            return None;
        }
        let half = s * h.x + t * h.y + cur.n * z2.sqrt();
        if !transmit {
            return finish(cur, wi, half * (2.0 * wi.dot(half)) - wi, h, eta, transmit);
        }
        // wi + η wo = μ H for a real μ (H is oriented afterwards): |wo| = 1 gives a quadratic in μ.
        // Both roots obey Snell's law tangentially; the physical one crosses the microfacet
        // (wo·H = (μ − wi·H)/η of the opposite sign to wi·H), the other stays on the incident side.
        let c = wi.dot(half);
        let disc = c * c - 1.0 + eta_rel * eta_rel;
        if !(disc >= 0.0) {
            return None;
        }
        let mu = c - disc.sqrt().copysign(c);
        (half * mu - wi) / eta_rel
    };
    finish(cur, wi, wo, h, eta, transmit)
}

/// Normalises a constructed direction and checks it: the requested side of the surface, and the
/// requested half vector when recomputed by the constraint itself.
fn finish(cur: &LocalGeometry, wi: DVec3, wo: DVec3, h: DVec2, eta: f64, transmit: bool) -> Option<DVec3> {
    let cos_i = cur.ng.dot(wi);
    let wo = wo.try_normalize()?;
    let same_side = cur.ng.dot(wo) * cos_i > 0.0;
    if same_side == transmit {
        return None;
    }
    // Check against the constraint itself, with neighbours one unit away along each direction.
    let at = |d: DVec3| LocalGeometry { p: cur.p + d, ..*cur };
    let achieved = half_vector(&at(wi), cur, &at(wo), eta).ok()?;
    ((achieved - h).length() <= INVERSION_TOLERANCE).then_some(wo)
}

/// |dω_o / dh⊥| at fixed ω_i: solid angle of the outgoing direction per unit area of the projected half
/// vector, |H~|² / (η² |ω_o·H|) (Walter et al. 2007; 4 |ω_o·H| for reflection) over |n·H| (the disk
/// measure is |n·H| dω_H). A Dirac vertex removes its delta in ω_o; manifold coordinates remove it in
/// h⊥, and this is the factor between the two. `wi`, `wo` are unit directions away from the vertex.
/// Index-matched transmission: h = P_st(wi + wo) moves as the projection of ω_o, so 1 / |n·ω_o|.
pub fn direction_per_half_vector(cur: &LocalGeometry, wi: DVec3, wo: DVec3, eta: f64) -> Option<f64> {
    let (cos_i, cos_o) = (cur.ng.dot(wi), cur.ng.dot(wo));
    let eta_rel = if cos_i * cos_o > 0.0 {
        1.0
    } else if cos_i > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    if cos_i * cos_o <= 0.0 && (eta_rel - 1.0).abs() < 1e-9 {
        let value = 1.0 / cur.n.dot(wo).abs();
        return (value.is_finite() && value > 0.0).then_some(value);
    }
    let h_raw = wi + wo * eta_rel;
    let h = h_raw.try_normalize()?;
    let value = h_raw.length_squared() / (eta_rel * eta_rel * wo.dot(h).abs()) / cur.n.dot(h).abs();
    (value.is_finite() && value > 0.0).then_some(value)
}

/// Σ ln |dω_o/dh⊥| over the inner vertices of `path` that scatter through a Dirac lobe (`delta`), at
/// their geometry `g` and index ratios `eta`: the factor between a walk's half-vector coordinates and the
/// chain's measure, which counts a Dirac vertex's outgoing direction (MEMLT and HSLT share it). `None`
/// where a factor vanishes or is not finite.
pub fn log_dirac_factor(path: &[Vertex], g: &[LocalGeometry], eta: &[f64]) -> Option<f64> {
    let mut sum = 0.0;
    for i in (1..g.len().saturating_sub(1)).filter(|&i| path[i].delta) {
        let wi = (g[i - 1].p - g[i].p).normalize();
        let wo = (g[i + 1].p - g[i].p).normalize();
        sum += direction_per_half_vector(&g[i], wi, wo, eta[i])?.ln();
    }
    sum.is_finite().then_some(sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;

    fn random_unit(rng: &mut Sampler) -> DVec3 {
        loop {
            let v = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - DVec3::ONE;
            if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
                return v.normalize();
            }
        }
    }

    fn vertex(rng: &mut Sampler) -> LocalGeometry {
        let ng = random_unit(rng);
        let n = (ng + random_unit(rng) * 0.2).normalize();
        let tu = random_unit(rng).cross(ng).normalize();
        LocalGeometry {
            p: DVec3::ZERO,
            ng,
            n,
            tu,
            tv: ng.cross(tu),
            dn_du: DVec3::ZERO,
            dn_dv: DVec3::ZERO,
            frame_ref: tu,
        }
    }

    #[test]
    fn constructed_directions_reproduce_the_requested_half_vector() {
        let mut rng = Sampler::from_seed(5);
        let (mut built, mut tried) = (0, 0);
        for _ in 0..4000 {
            let cur = vertex(&mut rng);
            let wi = random_unit(&mut rng);
            let h = DVec2::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5) * 1.2;
            for (transmit, eta) in [(false, 1.0), (true, 1.5), (true, 1.0 / 1.33)] {
                tried += 1;
                if let Some(wo) = scatter_with_half_vector(&cur, wi, h, eta, transmit) {
                    let at = |d: DVec3| LocalGeometry { p: d, ..cur };
                    let got = half_vector(&at(wi), &cur, &at(wo), eta).unwrap();
                    assert!((got - h).length() < 1e-7, "h {h:?} -> {got:?}");
                    assert_eq!(cur.ng.dot(wo) * cur.ng.dot(wi) < 0.0, transmit);
                    built += 1;
                }
            }
        }
        // Reflection below the surface, total internal reflection and grazing shading normals refuse
        // a share of the random requests; most must succeed.
        assert!(built * 2 > tried, "only {built} of {tried} requests built a direction");
    }

    #[test]
    fn index_matched_transmission_inverts_the_unnormalised_constraint() {
        let mut rng = Sampler::from_seed(6);
        let mut built = 0;
        for _ in 0..2000 {
            let cur = vertex(&mut rng);
            let wi = random_unit(&mut rng);
            // h = 0 is the straight line; the constraint is the unnormalised one, |h| up to 2.
            let straight = scatter_with_half_vector(&cur, wi, DVec2::ZERO, 1.0, true);
            if let Some(wo) = straight {
                assert!((wo + wi).length() < 1e-12, "{wo:?} vs {wi:?}");
            }
            let h = DVec2::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5) * 0.6;
            if let Some(wo) = scatter_with_half_vector(&cur, wi, h, 1.0, true) {
                let at = |d: DVec3| LocalGeometry { p: d, ..cur };
                let got = half_vector(&at(wi), &cur, &at(wo), 1.0).unwrap();
                assert!((got - h).length() < 1e-7, "h {h:?} -> {got:?}");
                assert!(cur.ng.dot(wo) * cur.ng.dot(wi) < 0.0);
                built += 1;
            }
        }
        // Shading normals tilted from ng and |h| up to 0.4 refuse some requests; most must succeed.
        assert!(built > 1000, "only {built} of 2000 index-matched requests built a direction");
    }

    #[test]
    fn mirror_factor_is_four_cosines() {
        let cur = LocalGeometry {
            p: DVec3::ZERO,
            ng: DVec3::Z,
            n: DVec3::Z,
            tu: DVec3::X,
            tv: DVec3::Y,
            dn_du: DVec3::ZERO,
            dn_dv: DVec3::ZERO,
            frame_ref: DVec3::X,
        };
        let wi = DVec3::new(0.6, 0.0, 0.8);
        let wo = DVec3::new(-0.6, 0.0, 0.8);
        let j = direction_per_half_vector(&cur, wi, wo, 1.0).unwrap();
        assert!((j - 4.0 * 0.8).abs() < 1e-12, "{j}");
    }
}
