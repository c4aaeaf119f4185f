//! HSLT half-vector proposals (supplement Sec. 1 "Anisotropic Half Vector Sampling"; paper Sec. 6): an
//! anisotropic Phong lobe (Ashikhmin and Shirley 2000) on the unit disk, rotated into the ray-differential
//! axes and moved to the current half vector by a Möbius automorphism of the disk, with its exact density.

use glam::{DMat2, DVec2};
use std::f64::consts::{FRAC_PI_2, PI};

/// Beckmann roughness to Phong exponent (Walter et al. 2007: n = 2/α² − 2), clamped at 0 so rough and
/// diffuse vertices get the widest lobe rather than a negative exponent.
pub fn beckmann_to_phong(alpha: f64) -> f64 {
    (2.0 / (alpha * alpha) - 2.0).max(0.0)
}

/// A zero-centred anisotropic Phong lobe on the unit disk: the projection (sinθ cosφ, sinθ sinφ) of
/// directions distributed ∝ cos^e(φ)θ with e(φ) = n_u cos²φ + n_v sin²φ. n_u sets the width along x.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhongDiskLobe {
    pub n_u: f64,
    pub n_v: f64,
}

impl PhongDiskLobe {
    pub fn new(n_u: f64, n_v: f64) -> PhongDiskLobe {
        let clean = |n: f64| if n.is_nan() { 0.0 } else { n.max(0.0) };
        PhongDiskLobe { n_u: clean(n_u), n_v: clean(n_v) }
    }

    fn exponent(&self, cos2_phi: f64) -> f64 {
        self.n_u * cos2_phi + self.n_v * (1.0 - cos2_phi)
    }

    /// Maps `u` in [0,1)² to a point strictly inside the disk (Ashikhmin–Shirley's quadrant warp).
    pub fn sample(&self, u: [f64; 2]) -> DVec2 {
        let quadrant = (u[0] * 4.0).floor().clamp(0.0, 3.0);
        let in_quadrant = u[0] * 4.0 - quadrant;
        let ratio = ((self.n_u + 1.0) / (self.n_v + 1.0)).sqrt();
        let base = (ratio * (FRAC_PI_2 * in_quadrant).tan()).atan();
        let phi = match quadrant as u8 {
            0 => base,
            1 => PI - base,
            2 => PI + base,
            _ => 2.0 * PI - base,
        };
        let (sin_phi, cos_phi) = phi.sin_cos();
        let e = self.exponent(cos_phi * cos_phi);
        // sin²θ = 1 − (1−u)^(2/(e+1)), written to keep its digits when e is huge (θ tiny).
        let sin2 = -((2.0 / (e + 1.0)) * (-u[1]).ln_1p()).exp_m1();
        DVec2::new(cos_phi, sin_phi) * sin2.clamp(0.0, 1.0).sqrt()
    }

    /// Density per unit disk area: sqrt((n_u+1)(n_v+1))/(2π) · (1−|z|²)^((e(φ)−1)/2); the solid-angle
    /// density of Ashikhmin–Shirley divided by cosθ = dA(z)/dω.
    pub fn pdf(&self, z: DVec2) -> f64 {
        let r2 = z.length_squared();
        if !(r2 < 1.0) {
            return 0.0;
        }
        let norm = ((self.n_u + 1.0) * (self.n_v + 1.0)).sqrt() / (2.0 * PI);
        if r2 == 0.0 {
            return norm;
        }
        let e = self.exponent(z.x * z.x / r2);
        norm * (0.5 * (e - 1.0) * (-r2).ln_1p()).exp()
    }
}

/// z̄·w as complex numbers.
fn conj_mul(a: DVec2, b: DVec2) -> DVec2 {
    DVec2::new(a.x * b.x + a.y * b.y, a.x * b.y - a.y * b.x)
}

fn complex_div(a: DVec2, b: DVec2) -> DVec2 {
    let d = b.length_squared();
    DVec2::new(a.x * b.x + a.y * b.y, a.y * b.x - a.x * b.y) / d
}

/// The disk automorphism taking 0 to `c` (|c| < 1): w = (z + c)/(1 + c̄z).
pub fn mobius(c: DVec2, z: DVec2) -> DVec2 {
    complex_div(z + c, DVec2::X + conj_mul(c, z))
}

/// Its inverse: z = (w − c)/(1 − c̄w).
pub fn mobius_inverse(c: DVec2, w: DVec2) -> DVec2 {
    complex_div(w - c, DVec2::X - conj_mul(c, w))
}

/// Area Jacobian |dz/dw|² of the inverse map: (1 − |c|²)² / |1 − c̄w|⁴.
pub fn mobius_inverse_jacobian(c: DVec2, w: DVec2) -> f64 {
    let denom = (DVec2::X - conj_mul(c, w)).length_squared();
    let num = 1.0 - c.length_squared();
    num * num / (denom * denom)
}

/// The proposal for one half vector: the lobe, rotated by `axes` (orthonormal columns: the lobe's x
/// axis goes to `axes.x_axis`), moved to `centre` (the current h⊥).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfVectorProposal {
    pub centre: DVec2,
    pub axes: DMat2,
    pub lobe: PhongDiskLobe,
}

impl HalfVectorProposal {
    /// `None` when the centre is not strictly inside the disk (a grazing half vector: no proposal).
    pub fn new(centre: DVec2, axes: DMat2, lobe: PhongDiskLobe) -> Option<HalfVectorProposal> {
        (centre.length_squared() < 1.0 && axes.is_finite()).then_some(HalfVectorProposal {
            centre,
            axes,
            lobe,
        })
    }

    /// A proposed half vector. `None` only if rounding put it on the rim (probability ~1e-16).
    pub fn sample(&self, u: [f64; 2]) -> Option<DVec2> {
        let w = mobius(self.centre, self.axes * self.lobe.sample(u));
        (w.length_squared() < 1.0).then_some(w)
    }

    /// The exact density per unit disk area of proposing `w`.
    pub fn pdf(&self, w: DVec2) -> f64 {
        if !(w.length_squared() < 1.0) {
            return 0.0;
        }
        let z = mobius_inverse(self.centre, w);
        self.lobe.pdf(self.axes.transpose() * z) * mobius_inverse_jacobian(self.centre, w)
    }
}

/// Smallest angular step: keeps the Phong exponent finite for near-specular vertices and degenerate
/// ray differentials (the value [C13] clamps its steps at).
pub const MIN_STEP: f64 = 1e-8;

/// Per-axis step sizes of paper Sec. 6: the BSDF-bandwidth step capped by the ray-differential lengths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepSizes {
    /// Orthonormal columns; the first follows the longer ray differential.
    pub axes: DMat2,
    /// Step along each axis, in half-vector (disk) units.
    pub sigma: DVec2,
}

impl StepSizes {
    /// The lobe whose Beckmann-equivalent width along each axis is that axis' step.
    pub fn lobe(&self) -> PhongDiskLobe {
        PhongDiskLobe::new(beckmann_to_phong(self.sigma.x), beckmann_to_phong(self.sigma.y))
    }

    pub fn proposal(&self, centre: DVec2) -> Option<HalfVectorProposal> {
        HalfVectorProposal::new(centre, self.axes, self.lobe())
    }
}

/// `bsdf_step` is the vertex's bandwidth step (e.g. its Beckmann α times a tunable factor); `dh_du` and
/// `dh_dv` are the changes of this half vector that move the image point by one ray-differential
/// footprint along the two image axes (R_j applied to the footprint at x_1). Axes are orthonormalised
/// keeping the longer one's direction; non-finite or vanishing differentials leave the BSDF step alone.
pub fn step_sizes(bsdf_step: f64, dh_du: DVec2, dh_dv: DVec2) -> StepSizes {
    let bsdf_step = if bsdf_step.is_nan() { MIN_STEP } else { bsdf_step.max(MIN_STEP) };
    let (lu, lv) = (dh_du.length(), dh_dv.length());
    if !(lu.is_finite() && lv.is_finite() && lu.max(lv) > 0.0) {
        return StepSizes { axes: DMat2::IDENTITY, sigma: DVec2::splat(bsdf_step) };
    }
    let (long, long_len, short_len) = if lu >= lv { (dh_du, lu, lv) } else { (dh_dv, lv, lu) };
    let first = long / long_len;
    StepSizes {
        axes: DMat2::from_cols(first, first.perp()),
        sigma: DVec2::new(bsdf_step.min(long_len), bsdf_step.min(short_len).max(MIN_STEP)),
    }
}

/// Paper Sec. 6.3: one step budget split among a path's perturbed vertices in proportion to their
/// bandwidths (rough vertices move most). Vertices with zero bandwidth (specular, index-matched) get 0.
pub fn bandwidth_shares(bandwidths: &[f64]) -> Vec<f64> {
    let total: f64 = bandwidths.iter().filter(|b| b.is_finite() && **b > 0.0).sum();
    bandwidths
        .iter()
        .map(|&b| if total > 0.0 && b.is_finite() && b > 0.0 { b / total } else { 0.0 })
        .collect()
}

/// A histogram of `samples` draws of a proposal against its density (statistical validation of the
/// kernel: its unit tests and stability case 11 share it).
#[derive(Clone, Copy, Debug)]
pub struct KernelHistogram {
    /// χ² over the bins expecting at least 20 samples, plus one pooled term for the rest and for
    /// everything outside the window; and its degrees of freedom.
    pub chi2_per_dof: f64,
    pub dof: usize,
    /// Share of the samples inside the window [lo, hi]² and the density's mass there.
    pub inside: f64,
    pub mass: f64,
    /// Samples at which the density is not positive (outside its own support).
    pub unsupported: usize,
}

/// Bins `samples` draws of `p` (random numbers from `seed`) on a `bins`² grid over [lo, hi] and compares
/// the counts with the density integrated over each bin by a `sub`² midpoint rule.
pub fn kernel_histogram(
    p: &HalfVectorProposal,
    (lo, hi): (DVec2, DVec2),
    (bins, sub): (usize, usize),
    samples: usize,
    seed: u64,
) -> KernelHistogram {
    let size = (hi - lo) / bins as f64;
    let mut counts = vec![0u64; bins * bins];
    let mut rng = crate::sampling::Sampler::from_seed(seed);
    let (mut inside, mut outside, mut unsupported) = (0u64, 0u64, 0usize);
    for _ in 0..samples {
        let Some(w) = p.sample([rng.next_f64(), rng.next_f64()]) else { continue };
        unsupported += !(p.pdf(w) > 0.0) as usize;
        let cell = ((w - lo) / size).floor();
        if cell.x >= 0.0 && cell.y >= 0.0 && cell.x < bins as f64 && cell.y < bins as f64 {
            counts[cell.y as usize * bins + cell.x as usize] += 1;
            inside += 1;
        } else {
            outside += 1;
        }
    }
    let (mut chi2, mut dof, mut mass) = (0.0, 0usize, 0.0);
    // Bins expecting fewer than 20 samples are pooled into one, so every term is near-Gaussian.
    let (mut pooled_count, mut pooled_expected) = (outside as f64, 0.0);
    for by in 0..bins {
        for bx in 0..bins {
            let mut integral = 0.0;
            for sy in 0..sub {
                for sx in 0..sub {
                    let offset = DVec2::new(
                        bx as f64 + (sx as f64 + 0.5) / sub as f64,
                        by as f64 + (sy as f64 + 0.5) / sub as f64,
                    );
                    integral += p.pdf(lo + offset * size);
                }
            }
            let bin_mass = integral * size.x * size.y / (sub * sub) as f64;
            mass += bin_mass;
            let expected = bin_mass * samples as f64;
            let count = counts[by * bins + bx] as f64;
            if expected >= 20.0 {
                chi2 += (count - expected).powi(2) / expected;
                dof += 1;
            } else {
                pooled_count += count;
                pooled_expected += expected;
            }
        }
    }
    pooled_expected += (1.0 - mass).max(0.0) * samples as f64;
    chi2 += (pooled_count - pooled_expected).powi(2) / pooled_expected.max(1.0);
    dof += 1;
    let inside = inside as f64 / samples as f64;
    KernelHistogram { chi2_per_dof: chi2 / dof as f64, dof, inside, mass, unsupported }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;

    fn rotation(angle: f64) -> DMat2 {
        let a = DVec2::from_angle(angle);
        DMat2::from_cols(a, a.perp())
    }

    fn random_in_disk(rng: &mut Sampler, max_radius: f64) -> DVec2 {
        DVec2::from_angle(2.0 * PI * rng.next_f64()) * max_radius * rng.next_f64().sqrt()
    }

    #[test]
    fn mobius_maps_the_disk_onto_itself_and_its_inverse_undoes_it() {
        let mut rng = Sampler::from_seed(21);
        for _ in 0..2000 {
            let c = random_in_disk(&mut rng, 0.999);
            let z = random_in_disk(&mut rng, 1.0);
            let w = mobius(c, z);
            assert!(w.length() < 1.0, "c={c:?} z={z:?} -> {w:?}");
            assert!((mobius_inverse(c, w) - z).length() < 1e-9, "round trip {c:?} {z:?}");
            // The rim goes to the rim, and the centre to c.
            let rim = DVec2::from_angle(2.0 * PI * rng.next_f64());
            assert!((mobius(c, rim).length() - 1.0).abs() < 1e-12);
            assert!((mobius(c, DVec2::ZERO) - c).length() < 1e-15);
            // The Jacobian equals a finite-difference determinant of the inverse map.
            let h = 1e-7 * (1.0 - w.length());
            let col = |d: DVec2| (mobius_inverse(c, w + d) - mobius_inverse(c, w - d)) / (2.0 * h);
            let fd = DMat2::from_cols(col(DVec2::X * h), col(DVec2::Y * h)).determinant();
            let exact = mobius_inverse_jacobian(c, w);
            assert!(((fd - exact) / exact).abs() < 1e-5, "{fd} vs {exact}");
        }
    }

    /// ∫ f over the unit disk in polar coordinates around `c`: trapezoid in angle (periodic, so
    /// spectrally accurate) and tanh-sinh in radius, whose nodes cluster double-exponentially at both
    /// ends: lobes far narrower than the grid at c, and the rim's integrable singularities.
    fn integrate_disk_around(c: DVec2, f: impl Fn(DVec2) -> f64) -> f64 {
        let angles = 1536;
        let (step, t_max) = (1.0 / 48.0, 4.5);
        let nodes = (t_max / step) as i64;
        let mut total = 0.0;
        for a in 0..angles {
            let dir = DVec2::from_angle(2.0 * PI * a as f64 / angles as f64);
            let along = c.dot(dir);
            let rho_max = -along + (along * along + 1.0 - c.length_squared()).sqrt();
            let mut radial = 0.0;
            for k in -nodes..=nodes {
                let t = k as f64 * step;
                let s = FRAC_PI_2 * t.sinh();
                // ρ/ρmax = (1 + tanh s)/2 = 1/(1 + e^{−2s}), without cancellation near either end.
                let frac = 1.0 / (1.0 + (-2.0 * s).exp());
                let dfrac = FRAC_PI_2 * t.cosh() * 2.0 / ((1.0 + (-2.0 * s).exp()) * (1.0 + (2.0 * s).exp()));
                let rho = rho_max * frac;
                radial += f(c + dir * rho) * rho * rho_max * dfrac * step;
            }
            total += radial * 2.0 * PI / angles as f64;
        }
        total
    }

    #[test]
    fn proposal_density_integrates_to_one_near_the_centre_and_near_the_rim() {
        let lobes = [(0.0, 0.0), (0.5, 3.0), (1.0, 20.0), (100.0, 3000.0), (1e5, 1e5)];
        let pivots = [0.0, 0.5, 0.9, 0.999];
        let mut worst: f64 = 0.0;
        for (n_u, n_v) in lobes {
            for (i, radius) in pivots.into_iter().enumerate() {
                let centre = DVec2::from_angle(0.4 + i as f64) * radius;
                let p =
                    HalfVectorProposal::new(centre, rotation(1.1 * i as f64), PhongDiskLobe::new(n_u, n_v))
                        .unwrap();
                let integral = integrate_disk_around(centre, |w| p.pdf(w));
                worst = worst.max((integral - 1.0).abs());
                assert!((integral - 1.0).abs() < 1e-5, "lobe ({n_u}, {n_v}) pivot |c|={radius}: {integral}");
            }
        }
        assert!(worst > 0.0, "quadrature is not exact, so a zero error would mean nothing was integrated");
    }

    /// χ²/dof of 200 000 samples on a 20² grid (10² sub-points per bin); every sample must lie in
    /// the density's support and the grid must hold enough populated bins.
    fn chi2_per_dof(p: &HalfVectorProposal, lo: DVec2, hi: DVec2, samples: usize, seed: u64) -> f64 {
        let h = kernel_histogram(p, (lo, hi), (20, 10), samples, seed);
        assert_eq!(h.unsupported, 0, "every sample lies in the support");
        assert!(h.dof > 50, "too few populated bins ({})", h.dof);
        h.chi2_per_dof
    }

    #[test]
    fn sample_histograms_match_the_density() {
        // A wide anisotropic lobe off-centre, over the whole disk.
        let p = HalfVectorProposal::new(DVec2::new(0.3, -0.5), rotation(0.7), PhongDiskLobe::new(5.0, 60.0))
            .unwrap();
        let stat = chi2_per_dof(&p, DVec2::splat(-1.0), DVec2::splat(1.0), 200_000, 1);
        // Under the null hypothesis χ²/dof ≈ 1 with sd √(2/dof) ≲ 0.2; 1.6 is a > 3σ miss.
        assert!(stat < 1.6, "whole disk: χ²/dof = {stat}");
        // A narrow lobe near the rim, where the Möbius map squeezes it: zoom onto it.
        let centre = DVec2::from_angle(2.0) * 0.97;
        let p = HalfVectorProposal::new(centre, rotation(-0.3), PhongDiskLobe::new(30.0, 400.0)).unwrap();
        let mut rng = Sampler::from_seed(3);
        let spread = (0..2000)
            .filter_map(|_| p.sample([rng.next_f64(), rng.next_f64()]))
            .map(|w| (w - centre).abs())
            .fold(DVec2::ZERO, DVec2::max);
        let stat = chi2_per_dof(&p, centre - spread, centre + spread, 200_000, 2);
        assert!(stat < 1.6, "near the rim: χ²/dof = {stat}");
    }

    #[test]
    fn reverse_densities_exist_wherever_forward_ones_do() {
        let mut rng = Sampler::from_seed(22);
        for _ in 0..1000 {
            let lobe = PhongDiskLobe::new(1e4 * rng.next_f64(), 1e4 * rng.next_f64());
            let x = random_in_disk(&mut rng, 0.999);
            let from_x = HalfVectorProposal::new(x, rotation(rng.next_f64() * 6.0), lobe).unwrap();
            let Some(y) = from_x.sample([rng.next_f64(), rng.next_f64()]) else { continue };
            let from_y = HalfVectorProposal::new(y, rotation(rng.next_f64() * 6.0), lobe).unwrap();
            let (fwd, rev) = (from_x.pdf(y), from_y.pdf(x));
            assert!(fwd > 0.0 && fwd.is_finite() && rev.is_finite(), "{fwd} {rev}");
            // Full support: the reverse density may underflow only for far jumps of very narrow lobes.
            assert!(rev > 0.0 || (x - y).length() > 1e-2, "x={x:?} y={y:?}");
        }
    }

    #[test]
    fn step_sizes_follow_the_bandwidth_and_the_ray_differentials() {
        assert_eq!(beckmann_to_phong(1.0), 0.0);
        assert!((beckmann_to_phong(0.1) - 198.0).abs() < 1e-9);
        assert_eq!(beckmann_to_phong(3.0), 0.0);
        // Long differential along (1, 1), short along (−1, 2): the first axis keeps the long one.
        let s = step_sizes(0.2, DVec2::new(-0.01, 0.02), DVec2::new(0.5, 0.5));
        assert!((s.axes.x_axis - DVec2::new(1.0, 1.0).normalize()).length() < 1e-15);
        assert!(s.axes.x_axis.dot(s.axes.y_axis).abs() < 1e-15);
        assert!((s.sigma - DVec2::new(0.2, 0.02f64.hypot(0.01))).length() < 1e-15, "{s:?}");
        // A rough vertex on a sharp image footprint is capped by the footprint; without differentials the
        // BSDF step rules.
        let s = step_sizes(1.0, DVec2::new(0.0, f64::NAN), DVec2::X);
        assert_eq!((s.axes, s.sigma), (DMat2::IDENTITY, DVec2::ONE));
        assert_eq!(s.lobe(), PhongDiskLobe::new(0.0, 0.0));
        let shares = bandwidth_shares(&[0.01, 0.0, 0.1, f64::NAN]);
        assert!((shares[0] - 1.0 / 11.0).abs() < 1e-15 && shares[1] == 0.0 && shares[3] == 0.0);
    }
}
