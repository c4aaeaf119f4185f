//! What Veach's perturbations share (Veach 1997, §11.4.2–11.4.4): retracing a specular chain
//! deterministically through the same-side Dirac lobes the old path used, the solid-angle-to-area
//! factors that make the traced vertices' densities, and the 1/r-distributed radial offsets; and
//! what their half-vector versions add (`hvlens`, `hvcaustic`): near-specular glossy vertices held at
//! their half vectors (HSLT's parameterisation, Kaplanyan et al. 2014, §4) with dω_h/dω_o.
//!
//! Densities follow the Dirac convention of `path_state`: a step through a Dirac lobe is taken with
//! probability 1 (the delta removed), so a chain traced from a direction of solid-angle density p_ω
//! has the area density p_ω · Π |cos θ_hit| / d² over its traced vertices.

use crate::bsdf::TransportMode;
use crate::geometry::{Frame, Ray, Vec2, Vec3};
use crate::metropolis::chain::{Failure, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::{visible, ScatterClass, Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// Smallest film offset of the lens and multi-chain perturbations, in pixels (Veach's r1).
pub const FILM_R1_PIXELS: f64 = 0.1;
/// Largest film offset as a fraction of the image area: r2 = sqrt(fraction · W · H / π), i.e. a
/// disc covering 5% of the image (Veach's and Mitsuba's default).
pub const FILM_R2_AREA_FRACTION: f64 = 0.05;

/// (r1, r2) of the film offset in pixels for this scene's film.
pub fn film_radius_range(scene: &Scene) -> (f64, f64) {
    let area = (scene.film.width * scene.film.height) as f64;
    let r2 = (FILM_R2_AREA_FRACTION * area / std::f64::consts::PI).sqrt();
    (FILM_R1_PIXELS, r2.max(FILM_R1_PIXELS * 2.0))
}

/// A value in [lo, hi] with density ∝ 1/value: hi · exp(−ln(hi/lo) u).
pub fn sample_reciprocal(lo: f64, hi: f64, u: f64) -> f64 {
    hi * (-(hi / lo).ln() * u).exp()
}

/// A film offset of length r ∝ 1/r on [r1, r2] at a uniform angle. Its density in film area,
/// 1 / (2π r² ln(r2/r1)), depends only on |offset|, so the move is symmetric and cancels.
pub fn sample_film_offset(scene: &Scene, rng: &mut Sampler) -> Vec2 {
    let (r1, r2) = film_radius_range(scene);
    let r = sample_reciprocal(r1, r2, rng.next_f64());
    let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
    Vec2::new((r * phi.cos()) as f32, (r * phi.sin()) as f32)
}

/// `w` turned by the polar angle θ at azimuth φ around itself.
pub fn rotate_direction(w: Vec3, theta: f64, phi: f64) -> Vec3 {
    let (st, ct) = (theta.sin(), theta.cos());
    let local = Vec3::new((st * phi.cos()) as f32, (st * phi.sin()) as f32, ct as f32);
    Frame::from_normal(w).to_world(local).normalize_or_zero()
}

/// A direction within θ ∈ [θ1, θ2] of `w`, θ ∝ 1/θ and uniform azimuth; returns it with θ. Its
/// solid-angle density, 1 / (2π ln(θ2/θ1) θ sin θ), is a function of the angle only.
pub fn perturb_direction(w: Vec3, theta1: f64, theta2: f64, rng: &mut Sampler) -> (Vec3, f64) {
    let theta = sample_reciprocal(theta1, theta2, rng.next_f64());
    let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
    (rotate_direction(w, theta, phi), theta)
}

/// The angle between two unit directions, accurate for tiny angles (atan2 of |a × b| and a · b).
pub fn angle_between(a: Vec3, b: Vec3) -> f64 {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    a.cross(b).length().atan2(a.dot(b))
}

/// Solid-angle density of `perturb_direction` at angle θ with range [θ1, θ2] (0 outside).
pub fn angular_density(theta: f64, theta1: f64, theta2: f64) -> f64 {
    if !(theta >= theta1 && theta <= theta2 && theta2 > theta1) {
        return 0.0;
    }
    1.0 / (2.0 * std::f64::consts::PI * (theta2 / theta1).ln() * theta.sin() * theta)
}

/// A ray leaving vertex `v` along `dir` on the exact line through `v.p`, skipping the surface it
/// leaves by starting at t = ε rather than by moving the origin off the surface (`spawn_ray`). A
/// moved origin shifts the line by ε = 1e-4 scene units, and a focusing specular chain (a glass ball
/// imaging a small light onto the floor) magnifies that shift, so retracing a chain would not land
/// back where it started; starting on the line keeps the retrace exact up to f32 rounding.
pub fn ray_from(v: &Vertex, dir: Vec3) -> Ray {
    let tmin = if v.is_surface() { v.eps } else { 0.0 };
    Ray { origin: v.p, dir, tmin, tmax: f32::INFINITY }
}

/// Π over j ≥ 1 of the solid-angle-to-area factor |cos| / d² at `chain[j]` seen from `chain[j−1]`
/// (an environment endpoint stays in solid angle): the density of a traced chain per unit p_ω.
pub fn conversion_product(scene: &Scene, chain: &[Vertex]) -> f64 {
    chain.windows(2).map(|w| w[0].convert_density(1.0, &w[1], scene) as f64).product()
}

/// The same product for the chain `chain` read from its last vertex to its first.
pub fn conversion_product_reversed(scene: &Scene, chain: &[Vertex]) -> f64 {
    chain.windows(2).map(|w| w[1].convert_density(1.0, &w[0], scene) as f64).product()
}

/// The first index ≥ `from` whose vertex is not `delta`.
pub fn first_non_delta(vertices: &[Vertex], from: usize) -> Option<usize> {
    (from..vertices.len()).find(|&i| !vertices[i].delta)
}

/// A non-Dirac surface vertex glossy enough (α < `threshold`) to be carried at its half vector.
pub fn is_held(v: &Vertex, threshold: f32) -> bool {
    v.kind == VertexKind::Surface
        && !v.delta
        && matches!(v.class, ScatterClass::Glossy { alpha } if alpha < threshold)
}

/// The relative index η_o/η_i that forms H = ω_i + η ω_o at `v`: 1 for reflection, the BSDF's ratio for
/// transmission, inverted when ω_i arrives from inside (as `manifold::constraint` does).
fn relative_eta(scene: &Scene, v: &Vertex, wi: DVec3, reflect: bool) -> f64 {
    if reflect {
        return 1.0;
    }
    let eta = v.bsdf(scene).map_or(1.0, |b| b.eta() as f64);
    if v.ng.as_dvec3().dot(wi) > 0.0 {
        eta
    } else {
        1.0 / eta
    }
}

/// The unit (generalised) half vector of `v` between ω_i and ω_o, on the side of the shading normal,
/// with dω_h/dω_o; `None` where ω_i = −η ω_o leaves it undefined. H is the same line whichever of the
/// two directions is called ω_i, so a chain may be traced from either end.
pub fn half_vector(scene: &Scene, v: &Vertex, wi: Vec3, wo: Vec3) -> Option<(DVec3, f64)> {
    let (wi, wo) = (wi.as_dvec3(), wo.as_dvec3());
    let reflect = v.reflects(wi.as_vec3(), wo.as_vec3());
    let eta = relative_eta(scene, v, wi, reflect);
    let raw = wi + wo * eta;
    let len2 = raw.length_squared();
    if !(len2 > 1e-12 * (1.0 + eta) * (1.0 + eta)) {
        return None;
    }
    let mut h = raw / len2.sqrt();
    if h.dot(v.frame.n.as_dvec3()) < 0.0 {
        h = -h;
    }
    let jacobian = eta * eta * wo.dot(h).abs() / len2;
    Some((h, jacobian))
}

/// The direction leaving `v` whose half vector with `wi` is `h` on the `reflect` side, if there is one.
fn direction_for_half_vector(scene: &Scene, v: &Vertex, wi: Vec3, h: DVec3, reflect: bool) -> Option<Vec3> {
    let wi = wi.as_dvec3();
    let h = if wi.dot(h) < 0.0 { -h } else { h };
    let cos_i = wi.dot(h);
    let wo = if reflect {
        h * (2.0 * cos_i) - wi
    } else {
        let eta = relative_eta(scene, v, wi, false);
        let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
        if sin2_t >= 1.0 {
            return None;
        }
        let cos_t = (1.0 - sin2_t).sqrt();
        -wi / eta + h * (cos_i / eta - cos_t)
    };
    let wo = wo.normalize_or_zero().as_vec3();
    let ng = v.ng;
    let same_side = ng.dot(wi.as_vec3()) * ng.dot(wo) > 0.0;
    (wo != Vec3::ZERO && same_side == reflect && v.reflects(wi.as_vec3(), wo) == reflect).then_some(wo)
}

/// Π dω_h/dω_o over the held inner vertices of `chain`, traced from its first vertex (ω_o points to
/// the next vertex) or, `from_last`, from its last (ω_o points to the previous one), so the light-side
/// chain of `hvcaustic` needs no reversed copy. With the held half vectors as coordinates, a traced
/// chain's density is this times the area conversion (the Jacobian is block triangular; `hvlens`
/// derives it).
pub fn held_jacobian_product(scene: &Scene, chain: &[Vertex], threshold: f32, from_last: bool) -> f64 {
    let mut product = 1.0;
    for j in 1..chain.len().saturating_sub(1) {
        if is_held(&chain[j], threshold) {
            let (from, to) = if from_last { (j + 1, j - 1) } else { (j - 1, j + 1) };
            let wi = chain[j].direction_to(&chain[from]);
            let wo = chain[j].direction_to(&chain[to]);
            product *= half_vector(scene, &chain[j], wi, wo).map_or(0.0, |(_, jac)| jac);
        }
    }
    product
}

/// Traces a specular chain again: `old` is the old chain in tracing order (`old[0]` the vertex the
/// ray leaves, `old[1..]` the vertices to replace, all but the last `delta`). Each new hit under an
/// old `delta` vertex continues through its BSDF's Dirac lobe on the side the old path used and is
/// marked `delta`; the hit under the last old vertex ends the chain, not `delta`. If that last old
/// vertex is an environment endpoint the chain must escape; if `ends_on_emitter`, the last hit must
/// be an emitter. Returns the new vertices replacing `old[1..]`, in tracing order.
pub fn trace_specular_chain(
    ctx: &mut PathContext,
    old: &[Vertex],
    ray: Ray,
    mode: TransportMode,
    ends_on_emitter: bool,
) -> Result<Vec<Vertex>, Failure> {
    trace_held_chain(ctx, old, ray, mode, ends_on_emitter, 0.0)
}

/// `trace_specular_chain` through held vertices too: an old inner vertex that is glossy below
/// `threshold` (`is_held`) must be replaced by a held one, which the chain leaves in the direction
/// whose half vector, in the new vertex's shading frame, is the old one's in its frame. Any other
/// non-Dirac inner vertex is a `chain_structure` failure. Threshold 0 holds nothing.
pub fn trace_held_chain(
    ctx: &mut PathContext,
    old: &[Vertex],
    mut ray: Ray,
    mode: TransportMode,
    ends_on_emitter: bool,
    threshold: f32,
) -> Result<Vec<Vertex>, Failure> {
    let scene = ctx.scene;
    let m = old.len() - 1;
    let mut out = Vec::with_capacity(m);
    for j in 1..=m {
        let end = &old[j];
        ctx.counters.rays += 1;
        let Some(si) = scene.intersect(&ray) else {
            if j == m && end.kind == VertexKind::InfiniteLight {
                let light = end.light.ok_or(Failure::Failed("miss"))?;
                out.push(Vertex::infinite(scene, light, ray.origin, ray.dir));
                return Ok(out);
            }
            return Err(Failure::Failed("miss"));
        };
        if j == m && end.kind == VertexKind::InfiniteLight {
            return Err(Failure::Failed("blocked_environment"));
        }
        let mut v = Vertex::surface(scene, &si, Spectrum::ONE);
        if j == m {
            if ends_on_emitter && v.light.is_none() {
                return Err(Failure::Failed("missed_emitter"));
            }
            out.push(v);
            return Ok(out);
        }
        let reflect = end.reflects(end.direction_to(&old[j - 1]), end.direction_to(&old[j + 1]));
        let wo = if end.delta {
            let wo =
                v.dirac_direction(scene, si.wi, reflect, mode).ok_or(Failure::Failed("no_dirac_lobe"))?;
            v.delta = true;
            wo
        } else if is_held(end, threshold) {
            if !is_held(&v, threshold) {
                return Err(Failure::Failed("chain_structure"));
            }
            let (h_old, _) =
                half_vector(scene, end, end.direction_to(&old[j - 1]), end.direction_to(&old[j + 1]))
                    .ok_or(Failure::Failed("degenerate_half_vector"))?;
            let h_new = v.frame.to_world(end.frame.to_local(h_old.as_vec3())).as_dvec3().normalize_or_zero();
            direction_for_half_vector(scene, &v, si.wi, h_new, reflect)
                .ok_or(Failure::Failed("no_direction_for_half_vector"))?
        } else {
            return Err(Failure::Failed("chain_structure"));
        };
        ray = ray_from(&v, wo);
        out.push(v);
    }
    Ok(out)
}

/// True if nothing blocks the new edge between `a` and `b` (counted as one ray).
pub fn connect_visible(ctx: &mut PathContext, a: &Vertex, b: &Vertex) -> bool {
    ctx.counters.rays += 1;
    ctx.counters.shadow_rays += 1;
    visible(ctx.scene, a, b)
}

/// Radians per pixel across the image (horizontal field of view / width), used to size angular
/// perturbations so they move the image by about as much as the lens perturbation does.
pub fn radians_per_pixel(scene: &Scene) -> f64 {
    let fov = 2.0 * (scene.camera.tan_half.x as f64).atan();
    fov / scene.film.width.max(1) as f64
}

/// The camera ray through film position `film`, or `outside_image` (NaN included).
pub fn primary_ray(scene: &Scene, film: Vec2) -> Result<Ray, Failure> {
    let (w, h) = (scene.film.width as f32, scene.film.height as f32);
    if !(film.x >= 0.0 && film.y >= 0.0 && film.x < w && film.y < h) {
        return Err(Failure::Failed("outside_image"));
    }
    Ok(scene.camera.generate_ray(film))
}

/// The camera-side specular chain of the lens and multi-chain perturbations: the primary ray through
/// `film`, traced through the old `x_1 … x_{c−1}` (all `delta`) to a new `y_c`. Returns
/// `[x_0, y_1, …, y_c]`.
pub fn trace_from_camera(
    ctx: &mut PathContext,
    old: &[Vertex],
    c: usize,
    film: Vec2,
) -> Result<Vec<Vertex>, Failure> {
    let ray = primary_ray(ctx.scene, film)?;
    let ends_on_emitter = c == old.len() - 1;
    let traced = trace_specular_chain(ctx, &old[..=c], ray, TransportMode::Radiance, ends_on_emitter)?;
    let mut out = Vec::with_capacity(c + 1);
    out.push(old[0]);
    out.extend(traced);
    Ok(out)
}

/// D(p) of the lens perturbation for the camera-side chain `p_0 … p_c`: the primary direction's
/// density, proportional to d film / dω, times the chain's area conversion.
pub fn camera_chain_density(scene: &Scene, chain: &[Vertex]) -> f64 {
    let dir = chain[0].direction_to(&chain[1]);
    scene.camera.pdf_dir(dir) as f64 * conversion_product(scene, chain)
}

/// The end of a lens-type move: the chain `y` = [x_0, y_1, …, y_c] retraced from the camera joins the
/// unchanged x_{c+1} … x_k of `x` (nothing to join when c = k), and T(y→x)/T(x→y) = D(x)/D(y) with
/// `density` the move's D of a camera chain p_0 … p_c.
pub fn join_camera_chain(
    ctx: &mut PathContext,
    x: &[Vertex],
    mut y: Vec<Vertex>,
    c: usize,
    density: impl Fn(&Scene, &[Vertex]) -> f64,
) -> Result<Proposal<PathState>, Failure> {
    if c < x.len() - 1 {
        if !y[c].connectible() {
            return Err(Failure::Failed("not_connectible"));
        }
        if !connect_visible(ctx, &y[c], &x[c + 1]) {
            return Err(Failure::Failed("occluded"));
        }
        y.extend_from_slice(&x[c + 1..]);
    }
    let scene = ctx.scene;
    let density_y = density(scene, &y[..=c]);
    let density_x = density(scene, &x[..=c]);
    if !(density_y > 0.0 && density_y.is_finite() && density_x.is_finite()) {
        return Err(Failure::Failed("zero_density"));
    }
    let state = PathState::new(scene, y).ok_or(Failure::Failed("no_contribution"))?;
    Ok(Proposal { state, t_ratio: density_x / density_y })
}
