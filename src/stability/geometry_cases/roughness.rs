//! Cases 1–3 of digest §5, the extremes of a vertex's lobe: near-specular roughness (steps → 0, f64
//! sampling of tiny lobes, bandwidth shares of supplement Figs. 15/17), very rough vertices (Phong
//! exponent clamped at 0, the whole-disk lobe, detailed balance), and grazing half vectors (|h⊥| → 1).

use glam::{DMat2, DVec2};

use super::support::{balance, hslt_paths, median_film_move, pinhole_xml, run_hslt_chains};
use crate::manifold::sampling::MIN_STEP;
use crate::manifold::{mobius_inverse, path_constraints, path_etas, path_geometry, step_sizes, StepSizes};
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::path::ScatterClass;
use crate::sampling::Sampler;
use crate::stability::scenes::{bundled, from_xml};
use crate::stability::{CaseReport, Effort};

/// A rough conductor plane (Beckmann α, or GGX) under a small area light placed at the mirror
/// direction of a camera looking at it, optionally with a diffuse back wall for longer paths.
fn glossy_plane(alpha: f64, distribution: &str, max_depth: u32, wall: bool) -> crate::scene::Scene {
    let wall = if wall {
        r#"<shape type="rectangle">
    <transform name="to_world"><scale value="6" /><rotate x="1" angle="90" /><translate y="5" z="2" /></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.6" /></bsdf>
  </shape>"#
    } else {
        ""
    };
    let sensor = pinhole_xml(30.0, "0, -4, 3", "0, 0, 0", "0, 0, 1", (32, 24));
    from_xml(
        &format!("glossy-plane-{alpha}"),
        &format!(
            r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="{max_depth}" /></integrator>
  {sensor}
  <shape type="rectangle">
    <transform name="to_world"><scale value="4" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="{distribution}" /><float name="alpha" value="{alpha}" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.3" /><lookat origin="0, 4, 3" target="0, 0, 0" up="0, 0, 1" /></transform>
    <emitter type="area"><rgb name="radiance" value="40, 40, 40" /></emitter>
  </shape>
  {wall}
</scene>"#
        ),
    )
}

/// Case 1: near-specular vertices (α from 1e-2 down to the BSDFs' floor of 1e-4).
pub fn near_specular(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();

    // (a) The proposal kernel for tiny steps, in f64: a Phong lobe with n = 2/σ² − 2 has
    // E[sin²θ] = 2/(n + 3) = 2σ²/(2 + σ²) exactly, so the mean |z|² of samples pulled back through the
    // Möbius map must equal it. |z|² is close to exponential (relative sd ≈ 1): with N samples the
    // relative standard error is 1/√N (0.7% at 2·10⁴), and 5% is more than six of them. A sampler
    // that lost its digits (1 − (1−u)^(2/(n+1)) in plain arithmetic) returns 0 or garbage below σ ≈ 1e-4.
    let samples = effort.scale(20_000, 200_000);
    let centre = DVec2::new(0.3, -0.2);
    let mut bad_density = 0usize;
    let mut ratios = Vec::new();
    for sigma in [1e-2, 1e-4, 1e-6, MIN_STEP] {
        let steps = StepSizes { axes: DMat2::IDENTITY, sigma: DVec2::splat(sigma) };
        let proposal = steps.proposal(centre).expect("centre inside the disk");
        // The same uniforms for every σ: sin²θ(u) ∝ σ² up to O(σ²), so the four ratios below may
        // differ by ~1e-4 plus rounding; anything more is lost precision.
        let mut rng = Sampler::from_seed(101);
        let mut sum = 0.0;
        for _ in 0..samples {
            let Some(w) = proposal.sample([rng.next_f64(), rng.next_f64()]) else {
                bad_density += 1;
                continue;
            };
            let q = proposal.pdf(w);
            bad_density += usize::from(!(q > 0.0 && q.is_finite()));
            sum += mobius_inverse(centre, w).length_squared();
        }
        ratios.push(sum / samples as f64 / (2.0 * sigma * sigma / (2.0 + sigma * sigma)));
    }
    let worst = (ratios[0] - 1.0).abs();
    let spread = ratios.iter().map(|r| (r - ratios[0]).abs()).fold(0.0, f64::max);
    report.measure(format!(
        "lobe spread for σ = 1e-2…1e-8: |E|z|²/(2σ²/(2+σ²)) − 1| = {worst:.1e} ({samples} samples), the same \
         to {spread:.1e} for every σ; {bad_density} non-finite or zero densities"
    ));
    report.check(worst < 0.05, format!("the lobe's spread is off by {worst:.3} of the Phong value"));
    report.check(
        spread < 1e-3,
        format!("tiny lobes lose digits: the spread ratio moves by {spread:e} down to σ = 1e-8"),
    );
    report.check(bad_density == 0, format!("{bad_density} samples of tiny lobes had no finite density"));
    let floor = step_sizes(0.0, DVec2::NAN, DVec2::NAN).sigma;
    report.check(
        floor == DVec2::splat(MIN_STEP),
        format!("a zero BSDF step is not clamped at 1e-8: {floor:?}"),
    );

    // (b) Fig. 17: a path through an α = 0.01 and an α = 0.1 dielectric. The step budget is shared
    // ∝ α, so the sharp vertex must take the smaller steps: compare the steps of both kinds of
    // vertex on the same paths.
    let fig17 = bundled("scenes/fig17/scene.xml", &[("resx", "32"), ("resy", "24"), ("max_depth", "6")]);
    let paths = hslt_paths(&fig17, 5, effort.scale(20_000, 80_000), effort.scale(300, 1200));
    let mutation = HalfVectorMutation::new(HalfVectorParams::default());
    let (mut mixed, mut sharp_smaller, mut over_bsdf) = (0usize, 0usize, 0usize);
    let mut ratios = Vec::new();
    for x in &paths {
        let inner = &x.vertices[1..x.vertices.len() - 1];
        let alpha = |v: &crate::path::Vertex| match v.class {
            ScatterClass::Glossy { alpha } => Some(alpha as f64),
            _ => None,
        };
        let has = |a: f64| inner.iter().any(|v| alpha(v).is_some_and(|b| (b - a).abs() < 1e-6));
        if !(has(0.01) && has(0.1)) {
            continue;
        }
        let Ok(prepared) = mutation.prepare(&fig17, &x.vertices, x.film) else { continue };
        mixed += 1;
        let mean_step = |a: f64| {
            let s: Vec<f64> = inner
                .iter()
                .zip(&prepared.steps)
                .filter(|(v, _)| alpha(v).is_some_and(|b| (b - a).abs() < 1e-6))
                .map(|(_, s)| 0.5 * (s.sigma.x + s.sigma.y))
                .collect();
            s.iter().sum::<f64>() / s.len() as f64
        };
        for (v, s) in inner.iter().zip(&prepared.steps) {
            if let Some(a) = alpha(v) {
                over_bsdf += usize::from(s.sigma.max_element() > a * (1.0 + 1e-12));
            }
        }
        let (sharp, rough) = (mean_step(0.01), mean_step(0.1));
        sharp_smaller += usize::from(sharp <= rough);
        ratios.push(rough / sharp);
    }
    ratios.sort_by(f64::total_cmp);
    let median_ratio = ratios.get(ratios.len() / 2).copied().unwrap_or(f64::NAN);
    report.measure(format!(
        "fig17: {mixed} paths through both α = 0.01 and α = 0.1 vertices, sharp step ≤ rough step on \
         {sharp_smaller}, median step ratio rough/sharp {median_ratio:.1}, {over_bsdf} steps above their α"
    ));
    // Fewer than 20 such paths would make the shares untested.
    report.check(mixed >= 20, format!("only {mixed} fig17 paths with both roughnesses"));
    report.check(over_bsdf == 0, format!("{over_bsdf} steps exceed their vertex's BSDF bandwidth"));
    // Shares ∝ α and a BSDF cap ∝ α both make the sharp vertex's step the smaller one; only a
    // ray-differential cap that is far tighter on the rough vertex could reverse that, so at least
    // 90% of the paths must show it.
    report.check(
        sharp_smaller * 10 >= mixed * 9,
        format!("the α = 0.01 vertex takes the larger step on {} of {mixed} paths", mixed - sharp_smaller),
    );
    let chains = run_hslt_chains(&fig17, &paths, effort.scale(20, 60), HalfVectorParams::default(), 7);
    report.measure(format!("fig17 chains: {}", chains.describe()));
    report.check(
        chains.stats.rejected_invalid == 0 && chains.bad_records == 0,
        "NaN reached the chain on fig17",
    );
    // The mixed-roughness path must still move: HSLT's point is that such paths mutate well.
    report.check(chains.acceptance() > 0.05, format!("fig17 acceptance {:.3}", chains.acceptance()));

    // (c) α → 1e-4 (the microfacet floor): a glossy vertex is never routed to a Dirac treatment, so
    // the chain must stay finite and account for every proposal, even where it hardly moves.
    let mut rows = Vec::new();
    for alpha in [1e-2, 1e-3, 1e-4] {
        let scene = glossy_plane(alpha, "beckmann", 3, false);
        let starts = hslt_paths(&scene, 11, effort.scale(8_000, 32_000), effort.scale(64, 256));
        let run = run_hslt_chains(&scene, &starts, effort.scale(20, 60), HalfVectorParams::default(), 3);
        rows.push(format!("α {alpha:e}: {} starts, {}", starts.len(), run.describe()));
        report.check(starts.len() >= 16, format!("α = {alpha}: only {} seed paths", starts.len()));
        report.check(
            run.stats.rejected_invalid == 0 && run.bad_records == 0 && run.counts_balance(),
            format!("α = {alpha}: invalid proposals or unaccounted outcomes ({})", run.describe()),
        );
    }
    report.measure(format!("glossy plane {}", rows.join("; ")));
    report.measure(
        "gap: vertices below a roughness threshold are not routed to a Fresnel-only specular treatment \
         (only smooth, Dirac vertices are held at h = 0; α is floored at 1e-4 by the BSDFs)",
    );
    report
}

/// Case 2: very rough vertices (α ≥ 1) next to diffuse ones.
pub fn very_rough(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    for alpha in [1.0, 3.0] {
        let scene = glossy_plane(alpha, "beckmann", 4, true);
        // The BSDF step alone is α ≥ 1, i.e. the Phong exponent 2/α² − 2 ≤ 0, clamped to the lobe
        // that covers the whole disk; with stratification off that is the proposal itself.
        let bsdf_only = HalfVectorParams { stratify: false, ..HalfVectorParams::default() };
        let paths = hslt_paths(&scene, 21, 8_000, 100);
        let mutation = HalfVectorMutation::new(bsdf_only);
        let (mut rough_vertices, mut whole_disk) = (0usize, 0usize);
        for x in &paths {
            let Ok(prepared) = mutation.prepare(&scene, &x.vertices, x.film) else { continue };
            for (v, s) in x.vertices[1..x.vertices.len() - 1].iter().zip(&prepared.steps) {
                if matches!(v.class, ScatterClass::Glossy { .. }) {
                    rough_vertices += 1;
                    let lobe = s.lobe();
                    whole_disk += usize::from(lobe.n_u == 0.0 && lobe.n_v == 0.0);
                }
            }
        }
        report.check(
            rough_vertices > 0 && whole_disk == rough_vertices,
            format!("α = {alpha}: {whole_disk} of {rough_vertices} rough vertices got the whole-disk lobe"),
        );
        // Detailed balance with the whole-disk lobe (BSDF steps) and with stratified steps. Under
        // the null hypothesis each identity's t over the passes follows Student's t with passes − 1
        // degrees of freedom; |t| > 5 then has probability below 1e-3 even for 8 passes.
        for (label, params) in [("bsdf steps", bsdf_only), ("stratified", HalfVectorParams::default())] {
            let b = balance(&scene, effort.scale(8, 24), 4_000, effort.scale(600, 2_000), params, 2);
            report.measure(format!(
                "α {alpha} {label}: {}; mean acceptance among valid {:.3}, failures {:?}",
                b.describe(),
                b.valid as f64 / b.proposals.max(1) as f64,
                b.stats.failed
            ));
            report
                .check(b.non_finite == 0, format!("α = {alpha} {label}: {} non-finite ratios", b.non_finite));
            // Whole-disk jumps mostly fail (the walk cannot reach far targets, or leaves the image),
            // which is the robust outcome; the identities still need a couple of hundred valid
            // proposals to have any power.
            report.check(
                b.valid >= 200 && b.proposals > 1000,
                format!("α = {alpha} {label}: {} of {} proposals valid", b.valid, b.proposals),
            );
            report.check(
                b.holds(5.0),
                format!("α = {alpha} {label}: detailed balance fails: {}", b.describe()),
            );
        }
        report.measure(format!(
            "α {alpha}: {whole_disk}/{rough_vertices} rough vertices with the whole-disk lobe"
        ));
    }
    report
}

/// A GGX plane seen by a camera at `elevation_deg` above it, with a point light beside the camera:
/// backscattering at grazing incidence, so the half vector lies near the rim of the disk.
fn grazing_plane(elevation_deg: f64) -> crate::scene::Scene {
    let e = elevation_deg.to_radians();
    let (y, z) = (-6.0 * e.cos(), 6.0 * e.sin());
    // The field of view equals the elevation, so every pixel sees the plane at between half and
    // one and a half times it.
    let fov = elevation_deg.max(1e-3);
    let sensor = pinhole_xml(fov, &format!("0, {y}, {z}"), "0, 0, 0", "0, 0, 1", (32, 24));
    from_xml(
        &format!("grazing-{elevation_deg}"),
        &format!(
            r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="2" /></integrator>
  {sensor}
  <shape type="rectangle">
    <transform name="to_world"><scale value="20" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="ggx" /><float name="alpha" value="0.6" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="0.3" y="{y}" z="{z}" /><rgb name="intensity" value="100, 100, 100" /></emitter>
</scene>"#
        ),
    )
}

/// Case 3: grazing half vectors, cosines and transfer determinants.
pub fn grazing(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    // (a) The Möbius-shifted kernel centred next to the rim: samples must stay inside the disk with a
    // finite, positive density, and the Jacobian (1−|c|²)²/|1−c̄w|⁴ must stay finite, down to
    // 1 − |c| = 1e-12 (f64 keeps ~4 digits of 1 − |w|² there).
    let mut rim_failures = 0usize;
    let mut drawn = 0usize;
    for gap in [1e-3, 1e-6, 1e-9, 1e-12] {
        let c = DVec2::from_angle(0.7) * (1.0 - gap);
        let steps = step_sizes(0.5, DVec2::NAN, DVec2::NAN);
        let p = steps.proposal(c).expect("inside the disk");
        let mut rng = Sampler::from_seed(33);
        for _ in 0..effort.scale(5_000, 50_000) {
            drawn += 1;
            match p.sample([rng.next_f64(), rng.next_f64()]) {
                Some(w) => {
                    let q = p.pdf(w);
                    rim_failures += usize::from(!(q > 0.0 && q.is_finite() && w.length() < 1.0));
                }
                None => rim_failures += 1,
            }
        }
    }
    report.measure(format!(
        "kernel at 1−|c| = 1e-3…1e-12: {rim_failures} of {drawn} samples off the disk or without density"
    ));
    // Rounding onto the rim is allowed (the mutation counts it as "grazing"), but it must be rare.
    report.check(rim_failures * 100 <= drawn, format!("{rim_failures} of {drawn} rim samples failed"));

    // (b) Real grazing paths: elevations of 3°, 0.3° and 0.03° put 1 − |h⊥| near e²/2.
    for elevation in [3.0, 0.3, 0.03] {
        let scene = grazing_plane(elevation);
        let starts = hslt_paths(&scene, 13, effort.scale(4_000, 16_000), effort.scale(64, 256));
        let (mut min_gap, mut nonfinite) = (f64::INFINITY, 0usize);
        let mut log_dets = Vec::new();
        for x in &starts {
            let eta = path_etas(&scene, &x.vertices);
            match path_constraints(&path_geometry(&x.vertices), &eta) {
                Ok(c) => {
                    min_gap = min_gap.min(1.0 - c.h[0].length());
                    match c.jacobian.factor() {
                        Ok(lu) => {
                            let t = lu.transfer_from_end().determinant();
                            let ln = lu.log_det().ln_abs;
                            nonfinite += usize::from(!(ln.is_finite() && t.is_finite() && t != 0.0));
                            log_dets.push(ln);
                        }
                        Err(_) => nonfinite += 1,
                    }
                }
                Err(_) => nonfinite += 1,
            }
        }
        // How far the sampled target lies from h(X), relative to the step the stratification asked
        // for: the Möbius map applied after the lobe contracts it by 1 − |c|² near the rim.
        let mutation = HalfVectorMutation::new(HalfVectorParams::default());
        let mut rng = Sampler::from_seed(8);
        let mut realised = Vec::new();
        for x in &starts {
            let Ok(prepared) = mutation.prepare(&scene, &x.vertices, x.film) else { continue };
            let (step, c) = (&prepared.steps[0], prepared.h[0]);
            let Some(w) = step.proposal(c).and_then(|p| p.sample([rng.next_f64(), rng.next_f64()])) else {
                continue;
            };
            realised.push((w - c).length() / step.sigma.max_element());
        }
        realised.sort_by(f64::total_cmp);
        let realised_median = realised.get(realised.len() / 2).copied().unwrap_or(f64::NAN);
        let run = run_hslt_chains(&scene, &starts, effort.scale(20, 60), HalfVectorParams::default(), 5);
        let bsdf_only = HalfVectorParams { stratify: false, ..HalfVectorParams::default() };
        let run_bsdf = run_hslt_chains(&scene, &starts, effort.scale(20, 60), bsdf_only, 5);
        let moved = median_film_move(&scene, &starts, HalfVectorParams::default(), 6);
        let moved_bsdf = median_film_move(&scene, &starts, bsdf_only, 6);
        let (lo, hi) =
            log_dets.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        report.measure(format!(
            "elevation {elevation}°: {} paths, min 1−|h⊥| {min_gap:.1e}, ln|det J| in [{lo:.1}, {hi:.1}], \
             {nonfinite} without finite det J/T; median |h′ − h| / σ {realised_median:.1e}; stratified chains: {}, median film move {moved:.2e} px; \
             BSDF-step chains: {}, median film move {moved_bsdf:.2e} px",
            starts.len(),
            run.describe(),
            run_bsdf.describe()
        ));
        report.check(starts.len() >= 16, format!("elevation {elevation}°: only {} paths", starts.len()));
        report.check(
            nonfinite == 0,
            format!("elevation {elevation}°: {nonfinite} paths without finite det J or T"),
        );
        for r in [&run, &run_bsdf] {
            report.check(
                r.stats.rejected_invalid == 0 && r.bad_records == 0 && r.counts_balance(),
                format!("elevation {elevation}°: NaN or unaccounted proposals ({})", r.describe()),
            );
        }
        if elevation < 0.1 {
            // e = 0.03° gives 1 − cos e ≈ 1.4e-7 for pure backscatter; the light's offset widens it,
            // but the case is only grazing if it stays far below 1e-3.
            report.check(min_gap < 1e-3, format!("the 0.03° paths are not grazing: 1 − |h| ≥ {min_gap:e}"));
        }
    }
    report.measure(
        "gap: near the rim the proposals are null moves (film move 0 px, acceptance 1): the steps are \
         set in h but applied before the Möbius map, which contracts them by 1 − |c|², so the walk \
         converges at once; safe (no NaN, no bias), but such chains only move through other mutations",
    );
    report
}
