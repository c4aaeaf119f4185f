//! Cases 7 and 8 of digest §5, the tangent frames half vectors are projected in (supplement §2.8):
//! a rotated (u, v) parameterisation must not change any proposal, a mesh without UVs must behave
//! alike, and flat-shaded meshes (dn = 0, normal jumps at edges) may fail walks but never bias.

use super::support::{
    balance, balance_where, bdpt, hit_towards, hslt_paths, pinhole_xml, relative_mismatch, run_hslt_chains,
    TempFile,
};
use crate::manifold::{path_etas, path_geometry, path_half_vectors};
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{Failure, Mutation, MutationStats, PathContext, PathState};
use crate::path::Vertex;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

/// A glossy saddle z = 0.25 (x² − y²) over [−1, 1]² as an OBJ grid without normals (the loader
/// interpolates smooth ones), with texture coordinates rotated by `uv_angle` about (0.5, 0.5), or
/// none at all.
fn saddle_obj(uv_angle: Option<f64>) -> String {
    let n = 16;
    let mut obj = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (2.0 * i as f64 / n as f64 - 1.0, 2.0 * j as f64 / n as f64 - 1.0);
            obj.push_str(&format!("v {x} {y} {}\n", 0.25 * (x * x - y * y)));
            if let Some(a) = uv_angle {
                let (u, v) = (0.5 * x, 0.5 * y);
                let (s, c) = a.sin_cos();
                obj.push_str(&format!("vt {} {}\n", 0.5 + c * u - s * v, 0.5 + s * u + c * v));
            }
        }
    }
    for j in 0..n {
        for i in 0..n {
            let k = |di: usize, dj: usize| (j + dj) * (n + 1) + i + di + 1;
            let (a, b, c, d) = (k(0, 0), k(1, 0), k(1, 1), k(0, 1));
            for tri in [[a, b, c], [a, c, d]] {
                let corner = |v: usize| if uv_angle.is_some() { format!("{v}/{v}") } else { v.to_string() };
                obj.push_str(&format!("f {} {} {}\n", corner(tri[0]), corner(tri[1]), corner(tri[2])));
            }
        }
    }
    obj
}

/// A low-poly sphere (8 rings × 12 segments) as an OBJ without normals or texture coordinates.
fn low_poly_sphere_obj() -> String {
    let (rings, segments) = (8, 12);
    let mut obj = String::from("v 0 0 1\n");
    for r in 1..rings {
        let theta = std::f64::consts::PI * r as f64 / rings as f64;
        for s in 0..segments {
            let phi = std::f64::consts::TAU * s as f64 / segments as f64;
            obj.push_str(&format!(
                "v {} {} {}\n",
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos()
            ));
        }
    }
    obj.push_str("v 0 0 -1\n");
    let ring = |r: usize, s: usize| 2 + (r - 1) * segments + s % segments;
    let bottom = 2 + (rings - 1) * segments;
    for s in 0..segments {
        obj.push_str(&format!("f 1 {} {}\n", ring(1, s), ring(1, s + 1)));
        obj.push_str(&format!("f {bottom} {} {}\n", ring(rings - 1, s + 1), ring(rings - 1, s)));
        for r in 1..rings - 1 {
            let (a, b, c, d) = (ring(r, s), ring(r + 1, s), ring(r + 1, s + 1), ring(r, s + 1));
            obj.push_str(&format!("f {a} {b} {c}\nf {a} {c} {d}\n"));
        }
    }
    obj
}

/// Camera, area light and a diffuse floor around one glossy mesh shape (`shape` holds its XML).
fn mesh_scene(name: &str, shape: &str, max_depth: u32) -> Scene {
    let sensor = pinhole_xml(40.0, "0.3, -3.5, 2.5", "0, 0, 0", "0, 0, 1", (32, 24));
    from_xml(
        name,
        &format!(
            r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="{max_depth}" /></integrator>
  {sensor}
  {shape}
  <shape type="rectangle">
    <transform name="to_world"><scale value="5" /><translate z="-1.2" /></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.4" /><lookat origin="-0.4, 3, 2.5" target="0, 0, 0" up="0, 0, 1" /></transform>
    <emitter type="area"><rgb name="radiance" value="30, 30, 30" /></emitter>
  </shape>
</scene>"#
        ),
    )
}

fn glossy_obj(file: &TempFile, extra: &str) -> String {
    format!(
        r#"<shape type="obj"><string name="filename" value="{}" />{extra}
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="0.15" /></bsdf>
  </shape>"#,
        file.0.display()
    )
}

/// `x` (a path of `from`) rebuilt in `to`, a scene with the same geometry in the same order: the
/// same camera, inner vertices re-found by casting rays at the same points, the same light vertex.
fn transplant(to: &Scene, x: &PathState) -> Option<PathState> {
    let n = x.vertices.len();
    let mut vertices = vec![Vertex::camera(to)];
    for v in &x.vertices[1..n - 1] {
        let hit = hit_towards(to, vertices.last()?, v.p)?;
        if (hit.p - v.p).length() > 1e-5 * (1.0 + v.p.length()) || hit.shape != v.shape {
            return None;
        }
        vertices.push(hit);
    }
    vertices.push(x.vertices[n - 1]);
    PathState::new(to, vertices)
}

/// Per group of chains (chain index mod `groups`), the weight HSLT-only chains record in each of
/// 6 × 4 film blocks, per recorded step.
fn film_blocks(
    scene: &Scene,
    starts: &[PathState],
    steps: usize,
    params: HalfVectorParams,
    groups: usize,
) -> Vec<Vec<f64>> {
    use crate::metropolis::{Chain, TargetFunction, WeightedMutation};
    let (nx, ny) = (6usize, 4usize);
    let (w, h) = (scene.film.width as f32, scene.film.height as f32);
    let bdpt = bdpt(scene);
    let mut out = vec![vec![0.0; nx * ny]; groups];
    let mut counts = vec![0usize; groups];
    for (c, start) in starts.iter().enumerate() {
        let g = c % groups;
        let mutation = Box::new(HalfVectorMutation::new(params));
        let mut chain = Chain::new(
            start.clone(),
            vec![WeightedMutation { mutation, weight: 1.0 }],
            TargetFunction::Luminance,
            Sampler::new(13, c as u64, 3),
        );
        let mut ctx = PathContext::new(scene, &bdpt);
        let hist = &mut out[g];
        let mut record = |state: &PathState, weight: f64| {
            let bx = ((state.film.x / w * nx as f32) as usize).min(nx - 1);
            let by = ((state.film.y / h * ny as f32) as usize).min(ny - 1);
            hist[by * nx + bx] += weight;
        };
        for _ in 0..steps {
            chain.step(&mut ctx, &mut record);
        }
        counts[g] += steps;
    }
    for (hist, n) in out.iter_mut().zip(counts) {
        for v in hist.iter_mut() {
            *v /= n.max(1) as f64;
        }
    }
    out
}

/// A glossy unit sphere (the bundled tessellation, uv poles at ±z) seen and lit from direction
/// `dir`: the highlight sits where `dir` meets the sphere.
fn glossy_sphere_seen_from(dir: glam::DVec3) -> Scene {
    let (eye, side) = (dir * 4.0, dir.any_orthonormal_vector() * 0.5);
    let light = eye + side;
    let up = side.normalize();
    let sensor = pinhole_xml(
        25.0,
        &format!("{}, {}, {}", eye.x, eye.y, eye.z),
        "0, 0, 0",
        &format!("{}, {}, {}", up.x, up.y, up.z),
        (24, 24),
    );
    from_xml(
        "glossy-sphere",
        &format!(
            r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="2" /></integrator>
  {sensor}
  <shape type="sphere">
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="0.1" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="{}" y="{}" z="{}" /><rgb name="intensity" value="50, 50, 50" /></emitter>
</scene>"#,
            light.x, light.y, light.z
        ),
    )
}

/// Case 7: rotating the (u, v) parameterisation, or dropping it.
pub fn frame_rotation(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    let angle = 1.1;
    let files = [
        TempFile::new("saddle-uv.obj", &saddle_obj(Some(0.0))),
        TempFile::new("saddle-uv-rotated.obj", &saddle_obj(Some(angle))),
        TempFile::new("saddle-no-uv.obj", &saddle_obj(None)),
    ];
    let scenes: Vec<Scene> = files
        .iter()
        .enumerate()
        .map(|(i, f)| mesh_scene(&format!("saddle-{i}"), &glossy_obj(f, ""), 3))
        .collect();
    let starts = hslt_paths(&scenes[0], 71, effort.scale(8_000, 32_000), effort.scale(300, 1200));
    let params = HalfVectorParams::default();

    // The same paths in the rotated scene: identical positions and contributions, ∂p/∂u turned by
    // the rotation of the parameterisation, and the half vectors unchanged (the projection frame
    // follows the normal, `normal_frame_reference`).
    let mut pairs = Vec::new();
    let (mut worst_f, mut turned, mut worst_h, mut compared_h) = (0.0f64, 0usize, 0.0f64, 0usize);
    for x in &starts {
        let Some(y) = transplant(&scenes[1], x) else { continue };
        let (fx, fy) = (super::support::target(x), super::support::target(&y));
        worst_f = worst_f.max(((fy - fx) / fx).abs());
        for (a, b) in x.vertices.iter().zip(&y.vertices).filter(|(a, _)| a.shape == 0) {
            let (da, db) = (a.derivatives.dpdu, b.derivatives.dpdu);
            turned += usize::from(da.angle_between(db) > 0.5);
        }
        let h = |s: &Scene, p: &PathState| {
            path_half_vectors(&path_geometry(&p.vertices), &path_etas(s, &p.vertices))
        };
        if let (Ok(ha), Ok(hb)) = (h(&scenes[0], x), h(&scenes[1], &y)) {
            for (a, b) in ha.iter().zip(&hb) {
                compared_h += 1;
                worst_h = worst_h.max((*a - *b).length());
            }
        }
        pairs.push((x.clone(), y));
    }
    let on_saddle = pairs.iter().flat_map(|(x, _)| &x.vertices).filter(|v| v.shape == 0).count();
    report.measure(format!(
        "{} of {} paths rebuilt in the rotated scene, contributions agree to {worst_f:.1e}, ∂p/∂u turned \
         at {turned} of {on_saddle} saddle vertices, {compared_h} half vectors agree to {worst_h:.1e}",
        pairs.len(),
        starts.len()
    ));
    report.check(
        pairs.len() * 10 >= starts.len() * 9 && pairs.len() >= 100,
        format!("only {} paths rebuilt", pairs.len()),
    );
    // f is a function of positions and isotropic BSDFs only: f32 rounding of the rebuilt hits.
    report.check(worst_f < 1e-3, format!("the rotation changes f by {worst_f:e}"));
    // The parameterisations must really differ (by 1.1 rad, distorted by the saddle's slope),
    // or the comparisons below compare identical inputs.
    report.check(
        turned * 10 >= on_saddle * 9 && on_saddle > 0,
        format!("∂p/∂u turned at {turned} of {on_saddle} vertices"),
    );
    // The rebuilt hits differ by f32 rounding (~1e-7 of the scene), which moves h by as much.
    report.check(worst_h < 1e-5, format!("the rotation changes half vectors by {worst_h:e}"));

    // The same random numbers from both: the proposal kernel, the walk and the densities are
    // rotation-equivariant, so the proposals must be the same paths with the same ratio, to the
    // walk's tolerance (1e-4 in h moves vertices ~1e-4 of a segment; ratios depend on h through
    // lobes of exponent ~100, hence 1e-2 in ln T).
    let bdpt_a = bdpt(&scenes[0]);
    let bdpt_b = bdpt(&scenes[1]);
    let mut ctx_a = PathContext::new(&scenes[0], &bdpt_a);
    let mut ctx_b = PathContext::new(&scenes[1], &bdpt_b);
    let mut mutation = HalfVectorMutation::new(params);
    let mut stats = MutationStats::default();
    let (mut agree, mut both_built, mut differ) = (0usize, 0usize, Vec::new());
    let (mut same_triangles, mut agree_same_triangles) = (0usize, 0usize);
    let mut worst_within: f64 = 0.0;
    let mut worst_move: f64 = 0.0;
    for (i, (x, y)) in pairs.iter().enumerate() {
        let mut rng_a = Sampler::new(7, i as u64, 0);
        let mut rng_b = Sampler::new(7, i as u64, 0);
        let pa = mutation.propose(x, &mut ctx_a, &mut rng_a, &mut stats);
        let pb = mutation.propose(y, &mut ctx_b, &mut rng_b, &mut stats);
        let same = match (&pa, &pb) {
            (Ok(a), Ok(b)) => {
                both_built += 1;
                let d = relative_mismatch(&a.state.vertices, &b.state.vertices);
                worst_move = worst_move.max(d);
                let dt = (a.t_ratio.ln() - b.t_ratio.ln()).abs();
                d < 1e-3 && (dt < 1e-2 || (a.t_ratio == 0.0 && b.t_ratio == 0.0))
            }
            (Err(Failure::Failed(a)), Err(Failure::Failed(b))) => a == b,
            _ => false,
        };
        // Proposals whose vertices all stay on their triangles never meet a frame seam.
        let stays = match &pa {
            Ok(a) => a.state.vertices.iter().zip(&x.vertices).all(|(p, q)| p.prim == q.prim),
            Err(_) => false,
        };
        same_triangles += usize::from(stays);
        // Within triangles only the paths are compared: the two frames differ by a rotation that
        // turns with the interpolated normal (s is ∂p/∂u projected off n), so J and the densities
        // of the ratio differ by a few percent, and only the chains' statistics must agree.
        let same_path = match (&pa, &pb) {
            (Ok(a), Ok(b)) => {
                let d = relative_mismatch(&a.state.vertices, &b.state.vertices);
                if stays {
                    worst_within = worst_within.max(d);
                }
                d < 1e-2
            }
            (Err(Failure::Failed(a)), Err(Failure::Failed(b))) => a == b,
            _ => false,
        };
        agree_same_triangles += usize::from(stays && same_path);
        if same {
            agree += 1;
        } else if differ.len() < 3 {
            let show = |p: &Result<crate::metropolis::Proposal<PathState>, Failure>| match p {
                Ok(p) => format!("ratio {:.4}", p.t_ratio),
                Err(e) => format!("{e:?}"),
            };
            differ.push(format!("{} vs {}", show(&pa), show(&pb)));
        }
    }
    report.measure(format!(
        "same random numbers: {agree} of {} proposals agree ({both_built} built in both, vertices within \
         {worst_move:.1e} of a segment); of the {same_triangles} that stay on their triangles \
         {agree_same_triangles} reach the same path (within {worst_within:.1e} of a segment); \
         disagreements e.g. {differ:?}",
        pairs.len()
    ));
    // Only f32 rounding of the rebuilt vertices separates the two computations; a walk that ends
    // just at its tolerance or a step-halving decision on a rounding difference may go either way,
    // one in a hundred.
    report.check(agree * 100 >= pairs.len() * 99, format!("only {agree} of {} proposals agree", pairs.len()));
    report.check(
        agree_same_triangles == same_triangles,
        format!(
            "only {agree_same_triangles} of {same_triangles} proposals within triangles reach the same path"
        ),
    );

    // Acceptance of HSLT-only chains on the three parameterisations, from the same starts. With
    // A accepted of N, the binomial standard error is √(p(1−p)/N) per scene; chains correlate
    // successive steps, so the allowance is 6 of them.
    let steps = effort.scale(10, 40);
    let mut rates = Vec::new();
    for (k, scene) in scenes.iter().enumerate() {
        let own: Vec<PathState> = if k == 0 {
            starts.clone()
        } else {
            starts.iter().filter_map(|x| transplant(scene, x)).collect()
        };
        let run = run_hslt_chains(scene, &own, steps, params, 9);
        report.check(run.stats.rejected_invalid == 0 && run.bad_records == 0, "NaN reached a saddle chain");
        rates.push((run.acceptance(), run.applicable()));
    }
    // The image: film blocks (6 × 4) of the states the chains record, with their weights, for
    // the same starts and random numbers in both parameterisations. Per group of chains the
    // paired difference of block fractions has mean 0 if the rotation changes nothing; its t over
    // 16 groups follows Student's t(15): E t² = 1.15, sd 1.84 per block, so the mean over 24
    // blocks has sd 0.38 and 1.15 + 5 · 0.38 ≈ 3.1 bounds it.
    let groups = 16;
    let hist_a = film_blocks(
        &scenes[0],
        &pairs.iter().map(|p| p.0.clone()).collect::<Vec<_>>(),
        steps,
        params,
        groups,
    );
    let hist_b = film_blocks(
        &scenes[1],
        &pairs.iter().map(|p| p.1.clone()).collect::<Vec<_>>(),
        steps,
        params,
        groups,
    );
    let mut t2 = Vec::new();
    for block in 0..hist_a[0].len() {
        let diff: Vec<f64> = (0..groups).map(|g| hist_a[g][block] - hist_b[g][block]).collect();
        let (m, se) = super::support::mean_se(&diff);
        if se > 0.0 {
            t2.push((m / se).powi(2));
        }
    }
    let mean_t2 = t2.iter().sum::<f64>() / t2.len().max(1) as f64;
    let bound = 1.15 + 5.0 * (3.39 / t2.len().max(1) as f64).sqrt();
    report.measure(format!(
        "image of the recorded states, uv vs rotated uv: mean t² {mean_t2:.2} over {} film blocks (bound {bound:.2})",
        t2.len()
    ));
    report.check(t2.len() >= 12, format!("only {} film blocks hold paths", t2.len()));
    report.check(mean_t2 < bound, format!("the rotation changes the image: mean t² {mean_t2:.2}"));
    let (p0, n0) = rates[0];
    let within = |(p, n): (f64, u64)| {
        let se = (p0 * (1.0 - p0) / n0 as f64 + p * (1.0 - p) / n as f64).sqrt();
        (p - p0).abs() <= 6.0 * se
    };
    report.measure(format!(
        "chain acceptance: uv {:.3}, rotated uv {:.3}, no uv {:.3}",
        rates[0].0, rates[1].0, rates[2].0
    ));
    report.check(
        within(rates[1]) && within(rates[2]),
        format!("acceptance depends on the parameterisation: {rates:?}"),
    );

    // Near a pole of the sphere's (u, v) map ∂p/∂u turns from one cap triangle to the next (2π/128
    // each); a frame built from it stalled 62% of the walks there, against 0.4% on the equator. The
    // normal-based frame has its own seam where |n·y| crosses 0.9.
    let mut success = Vec::new();
    let directions = [
        ("uv pole", glam::DVec3::Z),
        ("equator", glam::DVec3::new(0.5f64.cos(), 0.5f64.sin(), 0.0)),
        ("|n·y| = 0.9 frame switch", glam::DVec3::new(0.19f64.sqrt(), 0.9, 0.0)),
    ];
    for (label, dir) in directions {
        let scene = glossy_sphere_seen_from(dir);
        let starts = hslt_paths(&scene, 91, effort.scale(4_000, 16_000), effort.scale(150, 600));
        let run = run_hslt_chains(&scene, &starts, effort.scale(10, 40), params, 2);
        report.measure(format!("sphere {label}: {} starts, {}", starts.len(), run.describe()));
        report.check(starts.len() >= 50, format!("sphere {label}: only {} starts", starts.len()));
        report.check(
            run.stats.rejected_invalid == 0 && run.bad_records == 0 && run.counts_balance(),
            format!("sphere {label}: NaN or unaccounted proposals"),
        );
        success.push(run.walk_success());
    }
    // Binomial noise on ~1500 proposals is ~0.01; a frame that breaks at the pole drops the
    // success far more than the 0.05 allowed.
    report.check(
        success[0] >= success[1] - 0.05,
        format!("walks fail at the uv pole: {:.3} vs {:.3} on the equator", success[0], success[1]),
    );
    // The walk holds its start path's frame chart (`manifold::frame_chart`), so a vertex crossing the
    // switch keeps continuous coordinates (before, walks there succeeded 0.90 against 1.00), and each
    // kernel's density reads the other path in its own chart. Detailed balance must hold for the
    // proposals that change chart, which only this configuration has in number.
    report.check(
        success[2] >= success[1] - 0.05,
        format!("walks fail across the frame switch: {:.3} vs {:.3} on the equator", success[2], success[1]),
    );
    // Restricted to the proposals that change chart (a symmetric event), where the cross-chart terms
    // decide the ratio. Evaluating each density in its own path's chart instead fails this at the
    // table's counts (tail identity −0.017 ± 0.003 on the 3 278 switching proposals of 32 000; over
    // all of them the same error is only 2.7 standard errors).
    let seam = glossy_sphere_seen_from(directions[2].1);
    let mutation = HalfVectorMutation::new(params);
    let chart_of = |p: &PathState| mutation.prepare(&seam, &p.vertices, p.film).map(|prep| prep.chart).ok();
    let changes_chart = |x: &PathState, y: &PathState| chart_of(x) != chart_of(y);
    let b =
        balance_where(&seam, effort.scale(8, 16), 4_000, effort.scale(800, 2_000), params, 5, changes_chart);
    let switches = b.stats.sums.get("chart_switches").copied().unwrap_or(0.0);
    report.measure(format!(
        "across the frame switch, proposals that change chart: {}; {switches} chart changes counted by the mutation",
        b.describe()
    ));
    report.check(b.non_finite == 0, format!("frame switch: {} non-finite ratios", b.non_finite));
    report.check(
        b.valid >= effort.scale(400, 2_000) && b.valid as f64 <= switches,
        format!("{} valid proposals changed chart, the mutation counted {switches} changes", b.valid),
    );
    report.check(b.holds(5.0), format!("frame switch: detailed balance fails: {}", b.describe()));
    report
}

/// Case 8: a flat-shaded glossy mesh against the same mesh with interpolated normals.
pub fn flat_shading(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    let file = TempFile::new("low-poly-sphere.obj", &low_poly_sphere_obj());
    let flat =
        mesh_scene("flat-sphere", &glossy_obj(&file, r#"<boolean name="face_normals" value="true" />"#), 3);
    let smooth = mesh_scene("smooth-sphere", &glossy_obj(&file, ""), 3);
    let params = HalfVectorParams::default();
    let mut success = Vec::new();
    for (label, scene) in [("flat", &flat), ("smooth", &smooth)] {
        let starts = hslt_paths(scene, 81, effort.scale(8_000, 32_000), effort.scale(200, 800));
        let run = run_hslt_chains(scene, &starts, effort.scale(15, 50), params, 4);
        report.measure(format!("{label}: {} starts, {}", starts.len(), run.describe()));
        report.check(starts.len() >= 50, format!("{label}: only {} starts", starts.len()));
        report.check(
            run.stats.rejected_invalid == 0 && run.bad_records == 0 && run.counts_balance(),
            format!("{label}: NaN or unaccounted proposals"),
        );
        success.push(run.walk_success());
    }
    report.measure(format!("walk success flat {:.3} vs smooth {:.3}", success[0], success[1]));
    // Failures must be rejections that leave the chain's distribution alone: the detailed-balance
    // identities hold on the flat mesh. t over passes − 1 degrees of freedom; |t| > 5 has
    // probability below 1e-3 for 8 passes.
    let b = balance(&flat, effort.scale(8, 24), 4_000, effort.scale(600, 2_000), params, 8);
    report.measure(format!("flat {}; failures {:?}", b.describe(), b.stats.failed));
    report.check(b.non_finite == 0, format!("{} non-finite ratios on the flat mesh", b.non_finite));
    report.check(b.valid >= 200, format!("only {} valid proposals on the flat mesh", b.valid));
    report.check(b.holds(5.0), format!("detailed balance fails on the flat mesh: {}", b.describe()));
    report
}
