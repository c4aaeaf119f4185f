//! Case 11: the Möbius-shifted anisotropic Phong kernel of HSLT (supplement Sec. 1; digest 2.5.1)
//! sampled at centres |c| = 0, 0.5, 0.9, 0.999: a 2D histogram against the pdf integrated over each
//! bin (χ²), the pdf's mass in the window against the samples' share, and support symmetry.

use glam::{DMat2, DVec2};
use std::f64::consts::PI;

use crate::manifold::sampling::{kernel_histogram, mobius_inverse_jacobian};
use crate::manifold::{mobius_inverse, HalfVectorProposal, PhongDiskLobe};
use crate::sampling::Sampler;
use crate::stability::{CaseReport, Effort};

const BINS: usize = 48;
/// Sub-points per bin side of the midpoint rule that integrates the pdf over a bin: the lobes span the
/// window (it is sized from their own spread), so a bin is 1/48 of a lobe and the rule's relative
/// error (~(bin/4)²·|f''/f|/24 ≈ 1e-5) is far below the 1–2% counting noise per bin.
const SUB: usize = 4;

fn rotation(angle: f64) -> DMat2 {
    let a = DVec2::from_angle(angle);
    DMat2::from_cols(a, a.perp())
}

/// ln q(w) of a proposal written in log space (no underflow): ln of the lobe's normalisation plus
/// ((e − 1)/2)·ln(1 − |z|²) plus the Möbius Jacobian, z the pulled-back point. −∞ or NaN only where
/// the kernel has no support or the formula breaks.
fn log_pdf(p: &HalfVectorProposal, w: DVec2) -> f64 {
    let z = p.axes.transpose() * mobius_inverse(p.centre, w);
    let r2 = z.length_squared();
    let cos2 = if r2 > 0.0 { z.x * z.x / r2 } else { 1.0 };
    let e = p.lobe.n_u * cos2 + p.lobe.n_v * (1.0 - cos2);
    let norm = ((p.lobe.n_u + 1.0) * (p.lobe.n_v + 1.0)).sqrt() / (2.0 * PI);
    norm.ln() + 0.5 * (e - 1.0) * (-r2).ln_1p() + mobius_inverse_jacobian(p.centre, w).ln()
}

pub fn run(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    // 10^7 samples per centre in the table, split over the two lobes; a tenth of a million per lobe
    // and centre in the tests (still ~40 per populated bin at the window's edge).
    let per_lobe = effort.scale(150_000, 5_000_000);
    // A wide anisotropic lobe (a rough vertex) and a narrow one (α ≈ 0.07 against 0.3 across).
    let lobes = [PhongDiskLobe::new(5.0, 60.0), PhongDiskLobe::new(30.0, 400.0)];
    let mut worst_chi2: f64 = 0.0;
    let mut worst_mass: f64 = 0.0;
    let mut rows = Vec::new();
    for (ci, radius) in [0.0, 0.5, 0.9, 0.999].into_iter().enumerate() {
        for (li, lobe) in lobes.iter().enumerate() {
            let centre = DVec2::from_angle(0.7 + 1.3 * ci as f64) * radius;
            let p = HalfVectorProposal::new(centre, rotation(0.4 + ci as f64 + li as f64), *lobe)
                .expect("the centre is inside the disk");
            // The window: a box around the bulk of 4000 pilot samples (the Möbius map squeezes the lobe
            // by ~(1 − |c|²) near the rim, so a fixed window would put it in a handful of bins).
            let mut rng = Sampler::from_seed(900 + ci as u64);
            let pilot: Vec<DVec2> =
                (0..4000).filter_map(|_| p.sample([rng.next_f64(), rng.next_f64()])).collect();
            let lo = pilot.iter().fold(DVec2::splat(1.0), |a, w| a.min(*w)).max(DVec2::splat(-1.0));
            let hi = pilot.iter().fold(DVec2::splat(-1.0), |a, w| a.max(*w)).min(DVec2::splat(1.0));
            let h = kernel_histogram(&p, (lo, hi), (BINS, SUB), per_lobe, 1000 + 10 * ci as u64 + li as u64);
            // Under the null hypothesis χ²/dof has mean 1 and sd √(2/dof) (≈ 0.03 for ~2000 bins);
            // five of those above 1 is a miss of p < 1e-6, while a pdf that is 2% off in shape over
            // the lobe raises it by ~N·0.02²/bins ≈ 1 at the table's counts.
            report.check(
                h.unsupported == 0,
                format!("|c| = {radius}, lobe {li}: {} samples outside the support", h.unsupported),
            );
            let bound = 1.0 + 5.0 * (2.0 / h.dof as f64).sqrt();
            report.check(
                h.chi2_per_dof < bound,
                format!(
                    "|c| = {radius}, lobe {li}: χ²/dof = {:.3} over {} bins (bound {bound:.3})",
                    h.chi2_per_dof, h.dof
                ),
            );
            // The pdf's mass in the window equals the share of samples that fell there: binomial
            // noise √(p(1−p)/N) (at most 1.3e-3 in the tests) times five, plus 1e-4 for the midpoint
            // rule at the rim. A pdf not normalised to one fails this wherever the window holds most
            // samples.
            let sigma = (h.inside * (1.0 - h.inside) / per_lobe as f64).sqrt();
            let mass_error = (h.mass - h.inside).abs();
            report.check(
                mass_error < 5.0 * sigma + 1e-4,
                format!(
                    "|c| = {radius}, lobe {li}: pdf mass in window {:.5} vs sample share {:.5}",
                    h.mass, h.inside
                ),
            );
            worst_chi2 = worst_chi2.max(h.chi2_per_dof);
            worst_mass = worst_mass.max(mass_error);
            if li == 1 {
                rows.push(format!("|c|={radius}: χ²/dof {:.3}", h.chi2_per_dof));
            }
        }
    }
    report.measure(format!(
        "{} samples per centre ({} per lobe, 2 lobes, {BINS}² bins): worst χ²/dof {worst_chi2:.3} (narrow lobe: {}); \
         worst |pdf mass − sample share| in window {worst_mass:.1e}",
        2 * per_lobe,
        per_lobe,
        rows.join(", ")
    ));

    // Support symmetry: pairs X → Y as a chain makes them, each end with its own axes and exponents
    // (Y's kernel comes from Y's step sizes), centres up to |c| = 0.999, exponents up to 10^5.
    let pairs = effort.scale(100_000, 1_000_000);
    let mut rng = Sampler::from_seed(77);
    let lobe = |rng: &mut Sampler| {
        let n = |rng: &mut Sampler| 10f64.powf(5.0 * rng.next_f64()) - 1.0;
        PhongDiskLobe::new(n(rng), n(rng))
    };
    let (mut tried, mut forward_zero, mut reverse_underflow, mut reverse_hole) =
        (0usize, 0usize, 0usize, 0usize);
    let mut highest_underflow_log = f64::NEG_INFINITY;
    for _ in 0..pairs {
        let x = DVec2::from_angle(2.0 * PI * rng.next_f64()) * 0.999 * rng.next_f64().sqrt();
        let from_x = HalfVectorProposal::new(x, rotation(6.3 * rng.next_f64()), lobe(&mut rng)).unwrap();
        let Some(y) = from_x.sample([rng.next_f64(), rng.next_f64()]) else { continue };
        let Some(from_y) = HalfVectorProposal::new(y, rotation(6.3 * rng.next_f64()), lobe(&mut rng)) else {
            reverse_hole += 1;
            continue;
        };
        tried += 1;
        let fwd = from_x.pdf(y);
        if !(fwd > 0.0 && fwd.is_finite()) {
            forward_zero += 1;
        }
        let ln_rev = log_pdf(&from_y, x);
        if !ln_rev.is_finite() {
            reverse_hole += 1;
        } else if from_y.pdf(x) == 0.0 {
            // Only underflow of a far jump under a narrow lobe: the log density exists.
            reverse_underflow += 1;
            highest_underflow_log = highest_underflow_log.max(ln_rev);
        }
    }
    report.measure(format!(
        "support symmetry over {tried} pairs: q_X(Y) ≤ 0 {forward_zero}×, ln q_Y(X) not finite {reverse_hole}×, \
         q_Y(X) underflows to 0 {reverse_underflow}× (ln q ≤ {highest_underflow_log:.0} there)"
    ));
    report.check(tried > pairs / 2, "too few pairs sampled");
    report.check(forward_zero == 0, format!("{forward_zero} sampled points have no forward density"));
    report.check(
        reverse_hole == 0,
        format!("{reverse_hole} pairs have no reverse density: asymmetric support"),
    );
    // An f64 density reads 0 only below e^-745; anything above would be a genuine hole.
    report.check(
        reverse_underflow == 0 || highest_underflow_log < -700.0,
        format!("a reverse density reads 0 although ln q = {highest_underflow_log}"),
    );
    report
}
