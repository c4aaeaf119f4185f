//! Cases 5 and 6 of digest §5, where the Newton walk meets a degenerate or impossible system: a ball
//! lens focusing a point light (J singular where the receiver is conjugate to the light) and a glass
//! slab whose exit refraction is pushed past total internal reflection.

use glam::{DVec2, DVec3, Vec3};

use super::support::{
    cast_path, dense, hslt_paths, pinhole_xml, pinned, pivoted_det, run_hslt_chains, walk_to,
};
use crate::geometry::Ray;
use crate::manifold::{
    path_constraints, path_etas, path_geometry, path_half_vectors, WalkError, WalkSettings,
};
use crate::metropolis::mutations::halfvector::HalfVectorParams;
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

/// A rough glass ball (η = 1.5, α = 0.02) of radius `scale` at the origin; nothing else matters to
/// the walks, whose endpoints are pinned positions.
fn ball_lens(scale: f64) -> Scene {
    let d = 10.0 * scale;
    let sensor = pinhole_xml(30.0, &format!("0, 0, {d}"), "0, 0, 0", "0, 1, 0", (8, 8));
    from_xml(
        &format!("ball-lens-{scale}"),
        &format!(
            r#"<scene version="3.0.0">
  {sensor}
  <shape type="sphere"><float name="radius" value="{scale}" />
    <bsdf type="roughdielectric"><float name="alpha" value="0.02" /><float name="int_ior" value="1.5" /><float name="ext_ior" value="1.0" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="0" y="0" z="{d}" /><rgb name="intensity" value="1, 1, 1" /></emitter>
</scene>"#,
        ),
    )
}

/// The ball lens of `ball_lens(1)` seen by a camera at distance `d` behind it on the axis, with
/// the point light at distance `light` in front: what the camera sees is the light through the
/// lens, every pixel of it when the camera sits at the focus.
fn camera_behind_lens(d: f64, light: f64) -> Scene {
    let (eye, lamp) = (-lens_axis() * d, lens_axis() * light);
    let triple = |v: DVec3| format!("{}, {}, {}", v.x, v.y, v.z);
    let up = lens_axis().any_orthonormal_vector();
    let sensor = pinhole_xml(70.0, &triple(eye), "0, 0, 0", &triple(up), (24, 24));
    from_xml(
        &format!("camera-behind-lens-{d}"),
        &format!(
            r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="3" /></integrator>
  {sensor}
  <shape type="sphere">
    <bsdf type="roughdielectric"><float name="alpha" value="0.05" /><float name="int_ior" value="1.5" /><float name="ext_ior" value="1.0" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="{}" y="{}" z="{}" /><rgb name="intensity" value="50, 50, 50" /></emitter>
</scene>"#,
            lamp.x, lamp.y, lamp.z
        ),
    )
}

/// The lens axis: off the tessellation's poles and seam, so the axial hits land inside triangles.
fn lens_axis() -> DVec3 {
    DVec3::new(0.8, 0.5, 0.3).normalize()
}

/// Receiver (x_0, pinned) at distance `d` behind the lens, the two refractions through the ball on
/// the axis, and the point light (x_3, pinned) at distance `light` in front; all lengths × `scale`.
/// Both hits lie on the one axial ray: the second ray starts a little along it rather than at the
/// usual surface offset, whose absolute floor (`geometry::ray_epsilon`, 1e-4) is a tenth of a
/// 1e-3-scale lens and would move the far hit off the axis.
fn axial_path(scene: &Scene, scale: f64, d: f64, light: f64) -> Option<Vec<Vertex>> {
    let a = lens_axis();
    let receiver = pinned(scene, (-a * d * scale).as_vec3());
    let end = pinned(scene, (a * light * scale).as_vec3());
    let dir = a.as_vec3();
    let near = scene.intersect(&Ray::new(receiver.p, dir))?;
    let far = scene.intersect(&Ray::new(near.p + dir * (1e-3 * scale) as f32, dir))?;
    let surface = |si: &crate::scene::SurfaceInteraction| Vertex::surface(scene, si, Spectrum::ONE);
    Some(vec![receiver, surface(&near), surface(&far), end])
}

/// |det J| / ‖J‖_F⁴ (scale-free: J is 4 × 4) with the sign of det J, from a pivoted elimination.
fn relative_det(scene: &Scene, path: &[Vertex]) -> Option<f64> {
    let c = path_constraints(&path_geometry(path), &path_etas(scene, path)).ok()?;
    let m = dense(&c.jacobian);
    let frob2: f64 = m.iter().flatten().map(|v| v * v).sum();
    let (sign, ln) = pivoted_det(m);
    Some(sign * (ln - 2.0 * frob2.ln()).exp())
}

/// Case 5: the receiver moved through the ball lens's focus.
pub fn lens_focus(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    // Paraxial ball lens: focal length nR/(2(n−1)) = 1.5 from the centre (principal planes there);
    // a light at 6 images at 1/(1/1.5 − 1/6) = 2.0 behind the centre.
    let (light, focus) = (6.0, 2.0);
    let scene = ball_lens(1.0);
    let sweep: Vec<f64> = (0..=24).map(|i| 1.4 + 0.05 * i as f64).collect();
    let mut rows = Vec::new();
    for &d in &sweep {
        let path = axial_path(&scene, 1.0, d, light).expect("the axial rays hit the ball");
        rows.push((d, relative_det(&scene, &path).unwrap_or(f64::NAN)));
    }
    // On the axis the lens is rotationally symmetric, so both singular values of the fold vanish
    // together and det J touches zero without changing sign: locate the minimum of |relative det|
    // by golden-section search around the smallest sampled value.
    let at = |d: f64| {
        axial_path(&scene, 1.0, d, light)
            .and_then(|p| relative_det(&scene, &p))
            .map_or(f64::INFINITY, f64::abs)
    };
    let best = rows.iter().min_by(|a, b| a.1.abs().total_cmp(&b.1.abs())).map_or(focus, |r| r.0);
    let (mut lo, mut hi) = (best - 0.05, best + 0.05);
    let golden = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..60 {
        let (a, b) = (hi - golden * (hi - lo), lo + golden * (hi - lo));
        if at(a) < at(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    let d_star = 0.5 * (lo + hi);
    let far = rows.iter().map(|r| r.1.abs()).fold(0.0, f64::max);
    report.measure(format!(
        "|det J| / ‖J‖⁴ falls to {:.1e} at d* = {d_star:.4} (paraxial focus {focus}), from {far:.1e} at 0.6 away",
        at(d_star)
    ));
    // The tessellated sphere's interpolated normals give a curvature within ~1% of the true one,
    // and the axial hits sit ~1e-3 off the exact sphere, so the fold lies within 3% of the paraxial
    // image distance; a wrong block (a dropped curvature term) moves it by tens of percent.
    report.check((d_star - focus).abs() < 0.03 * focus, format!("fold at d = {d_star}, focus at {focus}"));

    // Walks from the axial path near the fold towards off-axis half vectors: the predictor's step
    // blows up like 1/σ_min. Every walk must either fail with a reason or end on a path that meets
    // its targets (checked afresh from the returned vertices): nothing clamped and accepted.
    let settings = WalkSettings::default();
    let mut rng = Sampler::from_seed(55);
    let (mut converged, mut verified, mut singular, mut other) = (0usize, 0usize, 0usize, 0usize);
    let mut near_det = f64::INFINITY;
    let per_offset = effort.scale(12, 48);
    for offset in [-1e-2, -1e-4, 0.0, 1e-4, 1e-2] {
        let d = d_star + offset;
        let Some(path) = axial_path(&scene, 1.0, d, light) else { continue };
        near_det = near_det.min(relative_det(&scene, &path).map_or(f64::INFINITY, f64::abs));
        let eta = path_etas(&scene, &path);
        let Ok(h0) = path_half_vectors(&path_geometry(&path), &eta) else { continue };
        for _ in 0..per_offset {
            let step = 10f64.powf(-3.0 + 2.0 * rng.next_f64());
            let dir = DVec2::from_angle(std::f64::consts::TAU * rng.next_f64());
            let target = vec![h0[0] + dir * step, h0[1]];
            match walk_to(&scene, &path, &target, &settings) {
                Ok(r) => {
                    converged += 1;
                    let achieved = path_half_vectors(&path_geometry(&r.path), &eta);
                    let tolerance = settings.tolerance.max(settings.precision_floor) * 1.01;
                    let meets = achieved
                        .is_ok_and(|h| h.iter().zip(&target).all(|(a, t)| (*a - *t).length() <= tolerance))
                        && r.path.iter().all(|v| v.p.is_finite());
                    verified += usize::from(meets);
                }
                Err(WalkError::Singular { .. }) => singular += 1,
                Err(_) => other += 1,
            }
        }
    }
    let walks = converged + singular + other;
    report.measure(format!(
        "{walks} walks within 1e-2 of the fold (relative det down to {near_det:.1e}): {converged} converged \
         ({verified} meet their targets afresh), {singular} refused as singular, {other} did not converge"
    ));
    report
        .check(converged == verified, format!("{} converged walks miss their targets", converged - verified));
    // The fold must cost something: if every walk there converged, the case did not reach it.
    report
        .check(singular + other > 0, "no walk near the fold failed: the configuration is not near-singular");
    report.check(verified > 0, "no walk near the fold converged: the case tests failures only");

    // The singularity test is relative: the same lens at 1e-3 and 1e3 times the size gives the same
    // scale-free determinant and the same LU verdict at every sampled distance (an absolute
    // threshold on det J, which scales as length⁻⁴, would flip between them).
    let mut worst_scale: f64 = 0.0;
    let mut verdicts_differ = 0usize;
    let mut per_scale = Vec::new();
    for scale in [1e-3, 1e3] {
        let before = worst_scale;
        worst_scale = 0.0;
        let scaled = ball_lens(scale);
        for &d in sweep.iter().chain(&[d_star]) {
            let (Some(p1), Some(ps)) =
                (axial_path(&scene, 1.0, d, light), axial_path(&scaled, scale, d, light))
            else {
                continue;
            };
            let (r1, rs) = (relative_det(&scene, &p1), relative_det(&scaled, &ps));
            if let (Some(r1), Some(rs)) = (r1, rs) {
                if r1.abs() > 1e-4 {
                    worst_scale = worst_scale.max(((rs - r1) / r1).abs());
                }
            }
            let ok = |s: &Scene, p: &[Vertex]| {
                path_constraints(&path_geometry(p), &path_etas(s, p))
                    .is_ok_and(|c| c.jacobian.factor().is_ok())
            };
            verdicts_differ += usize::from(ok(&scene, &p1) != ok(&scaled, &ps));
        }
        per_scale.push(format!("{scale:e}: {worst_scale:.1e}"));
        worst_scale = worst_scale.max(before);
    }
    report.measure(format!(
        "scaled by 1e-3 and 1e3: relative det agrees to {}, {verdicts_differ} LU verdicts differ",
        per_scale.join(", ")
    ));
    // f32 vertex positions carry ~1e-7 relative error at any scale, which the determinant's
    // cancellation near the fold amplifies (measured ~1e-5 where |relative det| > 1e-4); an
    // absolute epsilon anywhere in the constraint or the LU would change results by orders of
    // magnitude between the two scales. 1e-4 leaves a tenfold margin.
    report.check(worst_scale < 1e-4, format!("scale changes the relative determinant by {worst_scale:e}"));
    report.check(verdicts_differ == 0, format!("{verdicts_differ} singularity verdicts depend on the scale"));

    // The whole mutation with the camera (x_0) before, at and behind the focus: at the focus every
    // camera ray through the lens reaches the light, so J of the axial paths is singular there.
    for d in [0.85 * d_star, d_star, 1.15 * d_star] {
        let scene = camera_behind_lens(d, light);
        let starts = hslt_paths(&scene, 57, effort.scale(8_000, 32_000), effort.scale(100, 400));
        let run = run_hslt_chains(&scene, &starts, effort.scale(15, 50), HalfVectorParams::default(), 5);
        report.measure(format!("camera at {d:.3}: {} starts, {}", starts.len(), run.describe()));
        report.check(
            starts.len() >= 30,
            format!("camera at {d:.3}: only {} light paths through the lens", starts.len()),
        );
        report.check(
            run.stats.rejected_invalid == 0 && run.bad_records == 0 && run.counts_balance(),
            format!("camera at {d:.3}: NaN or unaccounted proposals ({})", run.describe()),
        );
    }
    report
}

/// A rough glass slab (η = 1.5, α = 0.02), 1 thick, below z = 1.
fn glass_slab() -> Scene {
    let sensor = pinhole_xml(30.0, "0, 0, 3", "0, 0, 0", "0, 1, 0", (8, 8));
    from_xml(
        "glass-slab",
        &format!(
            r#"<scene version="3.0.0">
  {sensor}
  <shape type="cube">
    <transform name="to_world"><scale x="20" y="20" z="0.5" /><translate z="0.5" /></transform>
    <bsdf type="roughdielectric"><float name="alpha" value="0.02" /><float name="int_ior" value="1.5" /><float name="ext_ior" value="1.0" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="0" y="0" z="3" /><rgb name="intensity" value="1, 1, 1" /></emitter>
</scene>"#
        ),
    )
}

/// Refracts at both vertices: the neighbours lie on opposite sides of the geometric surface.
fn refracts(path: &[Vertex], i: usize) -> bool {
    let ng = path[i].ng;
    ng.dot(path[i - 1].p - path[i].p) * ng.dot(path[i + 1].p - path[i].p) < 0.0
}

/// Whether half vector `h` at `v` (the slab's bottom) tilts the microfacet normal away from +x by
/// more than 2°, so the light cannot leave towards +x.
fn leans_back(v: &Vertex, h: DVec2) -> bool {
    let g = crate::manifold::LocalGeometry::from_vertex(v);
    let Some((s, t)) = g.shading_frame() else { return false };
    let tilt = s * h.x + t * h.y;
    // The outward normal is −z, so the facet leans back when its tangential part points to −x.
    tilt.x < -(2f64.to_radians().sin())
}

/// What the walks towards tilted exit facets of one slab configuration did.
#[derive(Default)]
struct TiltedExits {
    converged: usize,
    wrong: usize,
    failed: std::collections::BTreeMap<&'static str, usize>,
    worst_iterations: usize,
    failed_leaning_back: usize,
    leaning_back: usize,
}

/// Walks from the specular path between `from` and `to` (via aims on the top and bottom faces)
/// to `n` exit half vectors within `radius` of 0, the entry kept specular.
fn tilted_exits(
    scene: &Scene,
    ends: [Vec3; 2],
    aims: [Vec3; 2],
    radius: f64,
    n: usize,
    seed: u64,
) -> Result<(TiltedExits, f64), String> {
    let settings = WalkSettings::default();
    let start = cast_path(scene, pinned(scene, ends[0]), &aims, pinned(scene, ends[1]))
        .ok_or("the slab is missed")?;
    let base = walk_to(scene, &start, &[DVec2::ZERO, DVec2::ZERO], &settings)
        .map_err(|e| format!("the specular refraction path was not found: {e}"))?;
    let inside = (base.path[1].p - base.path[2].p).normalize();
    let inside_angle = inside.dot(base.path[2].ng).abs().acos().to_degrees() as f64;
    let mut out = TiltedExits::default();
    let mut rng = Sampler::from_seed(seed);
    for _ in 0..n {
        let target = [
            DVec2::ZERO,
            DVec2::from_angle(std::f64::consts::TAU * rng.next_f64()) * radius * rng.next_f64().sqrt(),
        ];
        let back = leans_back(&base.path[2], target[1]);
        out.leaning_back += usize::from(back);
        match walk_to(scene, &base.path, &target, &settings) {
            Ok(r) => {
                out.converged += 1;
                out.worst_iterations = out.worst_iterations.max(r.iterations);
                let eta = path_etas(scene, &r.path);
                let achieved = path_half_vectors(&path_geometry(&r.path), &eta);
                let tolerance = settings.tolerance.max(settings.precision_floor) * 1.01;
                let meets = achieved
                    .is_ok_and(|h| h.iter().zip(&target).all(|(a, t)| (*a - *t).length() <= tolerance));
                // A refraction target that converged to a reflection (or anything else) is wrong.
                out.wrong += usize::from(!(meets && refracts(&r.path, 1) && refracts(&r.path, 2)));
            }
            Err(e) => {
                out.failed_leaning_back += usize::from(back);
                *out.failed.entry(e.reason()).or_default() += 1;
            }
        }
    }
    Ok((out, inside_angle))
}

/// Case 6: exit refractions pushed past the critical angle.
pub fn tir_slab(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    let scene = glass_slab();
    let n = effort.scale(200, 1000);
    // Two configurations: light entering and leaving at ~87° (inside at the critical angle to
    // within 0.1°) with exit facets tilted up to 35°, and at ~89.99° with tilts up to 3°. In
    // both, facets leaning back cannot refract towards x_3 near where the path lies.
    let configurations = [
        (
            [Vec3::new(-11.2, 0.0, 1.5), Vec3::new(11.2, 0.0, -0.5)],
            [Vec3::new(-0.4, 0.0, 1.0), Vec3::new(0.5, 0.0, 0.0)],
            0.6,
        ),
        (
            [Vec3::new(-11.2, 0.0, 1.002), Vec3::new(11.2, 0.0, -0.002)],
            [Vec3::new(-0.4, 0.0, 1.0), Vec3::new(0.5, 0.0, 0.0)],
            0.05,
        ),
    ];
    let (mut converged, mut failed, mut wrong) = (0usize, 0usize, 0usize);
    let mut worst_iterations = 0usize;
    for (k, (ends, aims, radius)) in configurations.into_iter().enumerate() {
        match tilted_exits(&scene, ends, aims, radius, n, 66 + k as u64) {
            Ok((t, inside_angle)) => {
                let f: usize = t.failed.values().sum();
                report.measure(format!(
                    "inside angle {inside_angle:.2}°, tilts ≤ {radius}: {n} walks, {} converged, {f} failed {:?} \
                     ({} of {} leaning back), {} wrong solutions, at most {} iterations",
                    t.converged, t.failed, t.failed_leaning_back, t.leaning_back, t.wrong, t.worst_iterations
                ));
                converged += t.converged;
                failed += f;
                wrong += t.wrong;
                worst_iterations = worst_iterations.max(t.worst_iterations);
            }
            Err(e) => report.check(false, e),
        }
    }
    let total = 2 * n;
    report
        .check(wrong == 0, format!("{wrong} walks ended on a wrong solution (reflection or missed target)"));
    // Both outcomes must occur, or the case never reached the critical angle (or never left it).
    report.check(failed * 20 >= total, format!("only {failed} of {total} walks failed: TIR was not reached"));
    report.check(converged * 20 >= total, format!("only {converged} of {total} walks converged"));
    let cap = WalkSettings::default().max_iterations;
    report.check(
        worst_iterations <= cap,
        format!("a walk took {worst_iterations} iterations, above the cap of {cap}"),
    );
    report.measure("WalkError carries no path, so a half-converged path cannot be reused by construction");
    report
}
