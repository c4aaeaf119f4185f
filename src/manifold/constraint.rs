//! The generalised half-vector constraint of an inner path vertex (HSLT, Kaplanyan et al. 2014, Sec. 4;
//! Walter et al. 2007 for refraction) and its analytic derivative blocks A_i, B_i, C_i with respect to
//! the tangent-plane offsets of x_{i-1}, x_i, x_{i+1} (appendix Eq. 11), assembled into J for a path.
//! Over 600 lines because of its tests: half the file checks the analytic blocks against central
//! differences and known mirror, Snell and degenerate configurations, next to the equations they test.

use glam::{DMat2, DVec2, DVec3};

use super::blocktri::BlockTridiagonal;
use crate::path::Vertex;
use crate::scene::Scene;

/// Two eta values closer than this count as index-matched: the constraint then switches to the
/// unnormalised form, whose solution H~ = 0 is well-posed where normalising would divide by zero.
const INDEX_MATCH_TOLERANCE: f64 = 1e-9;

/// |H~| below this fraction of |wi| + eta |wo| means wi ≈ −eta·wo: the half vector has no direction.
const DEGENERATE_HALF_VECTOR: f64 = 1e-9;

/// First-order local geometry of a vertex in f64: a tangent offset `d` moves it to
/// `p + d.x·tu + d.y·tv` and turns its shading normal to `normalize(n + d.x·dn_du + d.y·dn_dv)`.
/// (tu, tv) are the Gram–Schmidt orthonormalised (∂p/∂u, ∂p/∂v), and (dn_du, dn_dv) went through the
/// same linear map, so offsets are in length units and 2×2 determinants are area ratios.
/// `frame_ref` is the fixed direction the half-vector projection frame is built from (see
/// `shading_frame`); it does not turn with the normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalGeometry {
    pub p: DVec3,
    pub ng: DVec3,
    pub n: DVec3,
    pub tu: DVec3,
    pub tv: DVec3,
    pub dn_du: DVec3,
    pub dn_dv: DVec3,
    pub frame_ref: DVec3,
}

/// The projection frame's reference direction, as a function of the shading normal only. A frame
/// built from ∂p/∂u jumps at triangle edges: without texture coordinates ∂p/∂u lies along an
/// arbitrary edge, and with them it is still constant per triangle, turning by 2π/segments from one
/// cap triangle to the next around a sphere's uv pole. The projected half vector then jumps at
/// every edge, which stalls the Newton walk there (digest 2.8; stability case 7 measured 62% failed
/// walks at a pole against 0.4% on the equator). The interpolated normal is continuous, so this
/// frame only jumps where |n·y| crosses 0.9; the threshold keeps |reference − n (reference·n)| ≥
/// 0.43, far from the frame's singularity.
pub fn normal_frame_reference(n: DVec3) -> DVec3 {
    if n.y.abs() < 0.9 {
        DVec3::Y
    } else {
        DVec3::X
    }
}

/// Why a vertex's constraint cannot be evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConstraintError {
    #[error("vertex {vertex}: a path segment has zero or non-finite length")]
    DegenerateSegment { vertex: usize },
    #[error("vertex {vertex}: wi = -eta wo, the half vector has no direction")]
    DegenerateHalfVector { vertex: usize },
    #[error("vertex {vertex}: the tangent frame is degenerate")]
    DegenerateFrame { vertex: usize },
}

fn dvec3(v: glam::Vec3) -> DVec3 {
    v.as_dvec3()
}

impl LocalGeometry {
    /// The local geometry of a path vertex. Vertices without a surface parameterisation (camera,
    /// point lights, degenerate ∂p/∂u) fall back to their shading frame with a constant normal.
    pub fn from_vertex(v: &Vertex) -> LocalGeometry {
        let n = dvec3(v.frame.n);
        let ng = match dvec3(v.ng).try_normalize() {
            Some(g) => g,
            None => n,
        };
        let d = &v.derivatives;
        let (dpdu, dpdv) = (dvec3(d.dpdu), dvec3(d.dpdv));
        let (dndu, dndv) = (dvec3(d.dndu), dvec3(d.dndv));
        let fallback = LocalGeometry {
            p: dvec3(v.p),
            ng,
            n,
            tu: dvec3(v.frame.s),
            tv: dvec3(v.frame.t),
            dn_du: DVec3::ZERO,
            dn_dv: DVec3::ZERO,
            frame_ref: dvec3(v.frame.s),
        };
        let len_u = dpdu.length();
        if !(len_u > 0.0) || !len_u.is_finite() || !dpdv.is_finite() {
            return fallback;
        }
        let tu = dpdu / len_u;
        let along = dpdv.dot(tu);
        let rest = dpdv - tu * along;
        let len_v = rest.length();
        // A parameterisation whose two derivatives are (nearly) parallel spans no plane.
        if !(len_v > 1e-9 * dpdv.length()) {
            return fallback;
        }
        let tv = rest / len_v;
        // [tu tv] = [dpdu dpdv] M with M upper triangular; the normal derivatives get the same M.
        let dn_du = dndu / len_u;
        let dn_dv = (dndv - dndu * (along / len_u)) / len_v;
        // The stored derivatives are of the unit normal, hence tangent to it; projecting removes
        // rounding so the offset model's derivative is exactly (dn_du, dn_dv).
        let tangential = |w: DVec3| w - n * n.dot(w);
        let (dn_du, dn_dv) = (tangential(dn_du), tangential(dn_dv));
        let frame_ref = normal_frame_reference(n);
        if !dn_du.is_finite() || !dn_dv.is_finite() {
            return LocalGeometry { tu, tv, frame_ref, ..fallback };
        }
        LocalGeometry { p: dvec3(v.p), ng, n, tu, tv, dn_du, dn_dv, frame_ref }
    }

    /// World displacement of a tangent offset.
    pub fn displacement(&self, offset: DVec2) -> DVec3 {
        self.tu * offset.x + self.tv * offset.y
    }

    /// The first-order model of this vertex moved by a tangent offset (tangents and normal derivatives
    /// are kept: second derivatives of p are not available from a triangle mesh).
    pub fn offset(&self, offset: DVec2) -> LocalGeometry {
        let n = (self.n + self.dn_du * offset.x + self.dn_dv * offset.y).normalize();
        LocalGeometry { p: self.p + self.displacement(offset), n, ..*self }
    }

    /// The orthonormal frame (s, t, n) in which half vectors are projected: s is `frame_ref` made
    /// orthogonal to n, t = n × s; continuous across triangles, whatever the (u, v) parameterisation.
    pub fn shading_frame(&self) -> Option<(DVec3, DVec3)> {
        let s = (self.frame_ref - self.n * self.frame_ref.dot(self.n)).try_normalize()?;
        Some((s, self.n.cross(s)))
    }
}

/// The constraint value of one inner vertex and its derivative blocks. Rows are the (s, t) components
/// of the projected half vector; columns are offsets along the (tu, tv) of the vertex differentiated by.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VertexConstraint {
    /// The projected half vector h⊥ = (H·s, H·t) (index-matched transmission: H~ unnormalised).
    pub h: DVec2,
    /// ∂h/∂x_{i-1}.
    pub a: DMat2,
    /// ∂h/∂x_i.
    pub b: DMat2,
    /// ∂h/∂x_{i+1}.
    pub c: DMat2,
    /// Relative index of refraction used in H~ = wi + eta_rel·wo (1 for reflection).
    pub eta_rel: f64,
    /// True when the unnormalised form was used (transmission with eta = 1).
    pub index_matched: bool,
}

/// How one vertex scatters between its neighbours: reflection uses eta_rel = 1; transmission uses the
/// BSDF's interior/exterior ratio `eta`, inverted when wi arrives from the inside (ng·wi < 0).
fn relative_eta(ng: DVec3, wi: DVec3, wo: DVec3, eta: f64) -> (f64, bool) {
    let (cos_i, cos_o) = (ng.dot(wi), ng.dot(wo));
    if cos_i * cos_o > 0.0 {
        return (1.0, false);
    }
    let eta_rel = if cos_i > 0.0 { eta } else { 1.0 / eta };
    (eta_rel, (eta_rel - 1.0).abs() < INDEX_MATCH_TOLERANCE)
}

/// The projected half vector of `cur` between `prev` and `next`, without derivatives. `eta` is the
/// BSDF's interior/exterior index ratio (`Bsdf::eta`; 1 for non-refracting BSDFs).
pub fn half_vector(
    prev: &LocalGeometry,
    cur: &LocalGeometry,
    next: &LocalGeometry,
    eta: f64,
) -> Result<DVec2, ConstraintError> {
    vertex_constraint(prev, cur, next, eta, false).map(|c| c.h)
}

/// The constraint of `cur` with its analytic derivative blocks (digest 2.2). Everything is
/// differentiated exactly, including the orthonormal frame's dependence on the turning normal, so the
/// blocks are the derivatives of `half_vector` under `LocalGeometry::offset`.
pub fn half_vector_constraint(
    prev: &LocalGeometry,
    cur: &LocalGeometry,
    next: &LocalGeometry,
    eta: f64,
) -> Result<VertexConstraint, ConstraintError> {
    vertex_constraint(prev, cur, next, eta, true)
}

fn vertex_constraint(
    prev: &LocalGeometry,
    cur: &LocalGeometry,
    next: &LocalGeometry,
    eta: f64,
    with_derivatives: bool,
) -> Result<VertexConstraint, ConstraintError> {
    let bad_segment = ConstraintError::DegenerateSegment { vertex: 0 };
    let to_prev = prev.p - cur.p;
    let to_next = next.p - cur.p;
    let (len_i, len_o) = (to_prev.length(), to_next.length());
    if !(len_i > 0.0 && len_o > 0.0 && len_i.is_finite() && len_o.is_finite()) {
        return Err(bad_segment);
    }
    let (wi, wo) = (to_prev / len_i, to_next / len_o);
    let (eta_rel, index_matched) = relative_eta(cur.ng, wi, wo, eta);
    let (s, t) = cur.shading_frame().ok_or(ConstraintError::DegenerateFrame { vertex: 0 })?;
    let h_raw = wi + wo * eta_rel;
    let h_len = h_raw.length();
    // Orientation into n's hemisphere is part of the constraint's definition; its sign enters dH.
    let orientation = if h_raw.dot(cur.n) < 0.0 { -1.0 } else { 1.0 };
    let h_dir = if index_matched {
        h_raw
    } else {
        if !(h_len > DEGENERATE_HALF_VECTOR * (1.0 + eta_rel)) {
            return Err(ConstraintError::DegenerateHalfVector { vertex: 0 });
        }
        h_raw * (orientation / h_len)
    };
    let h = DVec2::new(h_dir.dot(s), h_dir.dot(t));
    if !with_derivatives {
        return Ok(VertexConstraint {
            h,
            a: DMat2::ZERO,
            b: DMat2::ZERO,
            c: DMat2::ZERO,
            eta_rel,
            index_matched,
        });
    }

    // Derivative of a unit direction w = (q − p)/|q − p| when its far end q moves by d.
    let project_off = |w: DVec3, d: DVec3, len: f64| (d - w * w.dot(d)) / len;
    // dH from dH~: the normalisation's derivative, with the orientation sign carried along.
    let normalise = |dh_raw: DVec3| {
        if index_matched {
            dh_raw
        } else {
            let unit = h_raw / h_len;
            (dh_raw - unit * unit.dot(dh_raw)) * (orientation / h_len)
        }
    };
    let project = |dh: DVec3| DVec2::new(dh.dot(s), dh.dot(t));
    let column_prev = |d: DVec3| project(normalise(project_off(wi, d, len_i)));
    let column_next = |d: DVec3| project(normalise(project_off(wo, d, len_o) * eta_rel));
    // Moving cur moves both directions' near ends, and turns its normal and with it the frame.
    let column_cur = |d: DVec3, dn: DVec3| {
        let dh_raw = -project_off(wi, d, len_i) - project_off(wo, d, len_o) * eta_rel;
        let dh = normalise(dh_raw);
        let r = cur.frame_ref;
        let s_raw = r - cur.n * r.dot(cur.n);
        let s_len = s_raw.length();
        let ds_raw = -cur.n * r.dot(dn) - dn * r.dot(cur.n);
        let ds = (ds_raw - s * s.dot(ds_raw)) / s_len;
        let dt = dn.cross(s) + cur.n.cross(ds);
        DVec2::new(dh.dot(s) + h_dir.dot(ds), dh.dot(t) + h_dir.dot(dt))
    };
    Ok(VertexConstraint {
        h,
        a: DMat2::from_cols(column_prev(prev.tu), column_prev(prev.tv)),
        b: DMat2::from_cols(column_cur(cur.tu, cur.dn_du), column_cur(cur.tv, cur.dn_dv)),
        c: DMat2::from_cols(column_next(next.tu), column_next(next.tv)),
        eta_rel,
        index_matched,
    })
}

/// The constraints of a whole path x_0..x_k with fixed endpoints: current half vectors h_1..h_{k-1} and
/// the block-tridiagonal J (with the endpoint couplings in `a[0]` and `c[k-2]`).
#[derive(Clone, Debug)]
pub struct PathConstraints {
    pub h: Vec<DVec2>,
    pub jacobian: BlockTridiagonal,
    /// Per inner vertex: the unnormalised index-matched form was used.
    pub index_matched: Vec<bool>,
}

/// Evaluates every inner vertex's constraint. `eta[i]` is the interior/exterior index ratio of the BSDF
/// at `geometry[i]` (entries for the endpoints are ignored). Errors name the vertex's path index.
pub fn path_constraints(geometry: &[LocalGeometry], eta: &[f64]) -> Result<PathConstraints, ConstraintError> {
    assert_eq!(geometry.len(), eta.len(), "one eta per path vertex");
    let inner = geometry.len().saturating_sub(2);
    let mut out = PathConstraints {
        h: Vec::with_capacity(inner),
        jacobian: BlockTridiagonal {
            a: Vec::with_capacity(inner),
            b: Vec::with_capacity(inner),
            c: Vec::with_capacity(inner),
        },
        index_matched: Vec::with_capacity(inner),
    };
    for i in 1..=inner {
        let vc = half_vector_constraint(&geometry[i - 1], &geometry[i], &geometry[i + 1], eta[i])
            .map_err(|e| with_vertex(e, i))?;
        out.h.push(vc.h);
        out.jacobian.a.push(vc.a);
        out.jacobian.b.push(vc.b);
        out.jacobian.c.push(vc.c);
        out.index_matched.push(vc.index_matched);
    }
    Ok(out)
}

/// Only the half vectors of a path's inner vertices.
pub fn path_half_vectors(geometry: &[LocalGeometry], eta: &[f64]) -> Result<Vec<DVec2>, ConstraintError> {
    let mut h = Vec::with_capacity(geometry.len().saturating_sub(2));
    path_half_vectors_into(geometry, eta, &mut h)?;
    Ok(h)
}

/// `path_half_vectors` into `out` (cleared first), reusing its allocation.
pub fn path_half_vectors_into(
    geometry: &[LocalGeometry],
    eta: &[f64],
    out: &mut Vec<DVec2>,
) -> Result<(), ConstraintError> {
    assert_eq!(geometry.len(), eta.len(), "one eta per path vertex");
    out.clear();
    for i in 1..geometry.len().saturating_sub(1) {
        let h = half_vector(&geometry[i - 1], &geometry[i], &geometry[i + 1], eta[i])
            .map_err(|e| with_vertex(e, i))?;
        out.push(h);
    }
    Ok(())
}

fn with_vertex(e: ConstraintError, vertex: usize) -> ConstraintError {
    match e {
        ConstraintError::DegenerateSegment { .. } => ConstraintError::DegenerateSegment { vertex },
        ConstraintError::DegenerateHalfVector { .. } => ConstraintError::DegenerateHalfVector { vertex },
        ConstraintError::DegenerateFrame { .. } => ConstraintError::DegenerateFrame { vertex },
    }
}

/// The local geometry of every vertex of a path.
pub fn path_geometry(path: &[Vertex]) -> Vec<LocalGeometry> {
    path.iter().map(LocalGeometry::from_vertex).collect()
}

/// Per inner vertex, the reference direction its projection frame is built from: the *chart* in
/// which the path's half vectors are coordinates. A walk holds its start path's chart
/// (`path_geometry_in_chart`), so a vertex that moves across the seam of `normal_frame_reference`
/// keeps a continuous h⊥ instead of one that jumps by the angle between the two references.
pub fn frame_chart(geometry: &[LocalGeometry]) -> Vec<DVec3> {
    let inner = geometry.len().saturating_sub(2);
    geometry[1..=inner].iter().map(|g| g.frame_ref).collect()
}

/// `path_geometry` with the inner vertices' projection frames built from `chart` (one reference per
/// inner vertex, from `frame_chart`) instead of from their own normals; `None` is `path_geometry`.
pub fn path_geometry_in_chart(path: &[Vertex], chart: Option<&[DVec3]>) -> Vec<LocalGeometry> {
    let mut geometry = Vec::with_capacity(path.len());
    path_geometry_in_chart_into(path, chart, &mut geometry);
    geometry
}

/// `path_geometry_in_chart` into `out` (cleared first), reusing its allocation.
pub fn path_geometry_in_chart_into(path: &[Vertex], chart: Option<&[DVec3]>, out: &mut Vec<LocalGeometry>) {
    out.clear();
    out.extend(path.iter().map(LocalGeometry::from_vertex));
    if let Some(chart) = chart {
        assert_eq!(chart.len() + 2, path.len(), "one chart reference per inner vertex");
        for (g, reference) in out[1..].iter_mut().zip(chart) {
            g.frame_ref = *reference;
        }
    }
}

/// The eta of each path vertex's BSDF (1 for endpoints and non-refracting BSDFs).
pub fn path_etas(scene: &Scene, path: &[Vertex]) -> Vec<f64> {
    path.iter().map(|v| v.bsdf(scene).map_or(1.0, |b| b.eta() as f64)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Frame, Vec2, Vec3};
    use crate::path::{ScatterClass, VertexKind};
    use crate::sampling::Sampler;
    use crate::scene::SurfaceDerivatives;
    use crate::spectrum::Spectrum;

    fn uniform(rng: &mut Sampler, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * rng.next_f64()
    }

    fn random_vec(rng: &mut Sampler) -> DVec3 {
        DVec3::new(uniform(rng, -1.0, 1.0), uniform(rng, -1.0, 1.0), uniform(rng, -1.0, 1.0))
    }

    /// A curved vertex at `p`: geometric normal `ng`, shading normal tilted from it, orthonormal tangents
    /// in the geometric plane, and normal derivatives of order one.
    fn random_vertex(rng: &mut Sampler, p: DVec3, ng: DVec3) -> LocalGeometry {
        let n = (ng + random_vec(rng) * 0.15).normalize();
        let tu = (random_vec(rng).cross(ng)).normalize();
        let tv = ng.cross(tu);
        let tangential = |w: DVec3| w - n * n.dot(w);
        LocalGeometry {
            p,
            ng,
            n,
            tu,
            tv,
            dn_du: tangential(random_vec(rng) * 0.8),
            dn_dv: tangential(random_vec(rng) * 0.8),
            frame_ref: tu,
        }
    }

    #[derive(Clone, Copy, Debug)]
    enum Scattering {
        Reflection,
        Refraction { eta: f64 },
    }

    /// prev, cur, next with next on the far side for refraction, away from grazing and from the
    /// orientation flip of H (where the constraint is not differentiable).
    fn random_configuration(
        rng: &mut Sampler,
        kind: Scattering,
    ) -> (LocalGeometry, LocalGeometry, LocalGeometry) {
        loop {
            let ng = (DVec3::Z + random_vec(rng) * 0.4).normalize();
            let p = random_vec(rng) * 0.3;
            let cur = random_vertex(rng, p, ng);
            let away = |rng: &mut Sampler, side: f64| loop {
                let d = random_vec(rng).normalize();
                if side * d.dot(ng) > 0.25 {
                    return d * uniform(rng, 0.4, 3.0);
                }
            };
            let prev_side = if rng.next_f64() < 0.5 { 1.0 } else { -1.0 };
            let next_side = match kind {
                Scattering::Reflection => prev_side,
                Scattering::Refraction { .. } => -prev_side,
            };
            let prev_p = cur.p + away(rng, prev_side);
            let next_p = cur.p + away(rng, next_side);
            let prev_ng = random_vec(rng).normalize();
            let prev = random_vertex(rng, prev_p, prev_ng);
            let next_ng = random_vec(rng).normalize();
            let next = random_vertex(rng, next_p, next_ng);
            let eta = match kind {
                Scattering::Reflection => 1.0,
                Scattering::Refraction { eta } => eta,
            };
            let (wi, wo) = ((prev.p - cur.p).normalize(), (next.p - cur.p).normalize());
            let (eta_rel, matched) = relative_eta(cur.ng, wi, wo, eta);
            let h_raw = wi + wo * eta_rel;
            if matched || (h_raw.normalize().dot(cur.n).abs() > 0.1 && h_raw.length() > 0.1) {
                return (prev, cur, next);
            }
        }
    }

    fn max_abs(m: DMat2) -> f64 {
        m.abs().to_cols_array().into_iter().fold(0.0, f64::max)
    }

    #[test]
    fn analytic_blocks_equal_central_differences() {
        let mut rng = Sampler::from_seed(11);
        let kinds = [
            Scattering::Reflection,
            Scattering::Refraction { eta: 1.5 },
            Scattering::Refraction { eta: 1.0 / 1.33 },
            Scattering::Refraction { eta: 1.0 },
        ];
        // Lengths and curvatures are O(1): with step 1e-5 the central difference's truncation error is
        // ~1e-10 and its rounding error ~ε/1e-5 ≈ 2e-11, so 1e-7 of the row's largest entry separates
        // them from any real mistake (a dropped term or a wrong sign is O(1) of the row).
        let step = 1e-5;
        let mut worst: f64 = 0.0;
        for kind in kinds {
            for _ in 0..200 {
                let (prev, cur, next) = random_configuration(&mut rng, kind);
                let eta = match kind {
                    Scattering::Reflection => 1.0,
                    Scattering::Refraction { eta } => eta,
                };
                let vc = half_vector_constraint(&prev, &cur, &next, eta).unwrap();
                assert_eq!(vc.index_matched, matches!(kind, Scattering::Refraction { eta } if eta == 1.0));
                let row_scale = max_abs(vc.a).max(max_abs(vc.b)).max(max_abs(vc.c));
                let mut numeric = [DMat2::ZERO; 3];
                for (which, block) in numeric.iter_mut().enumerate() {
                    for axis in 0..2 {
                        let d = if axis == 0 { DVec2::X * step } else { DVec2::Y * step };
                        let moved = |sign: f64| {
                            let mut v = [prev, cur, next];
                            v[which] = v[which].offset(d * sign);
                            half_vector(&v[0], &v[1], &v[2], eta).unwrap()
                        };
                        *block.col_mut(axis) = (moved(1.0) - moved(-1.0)) / (2.0 * step);
                    }
                }
                for (analytic, numeric) in [vc.a, vc.b, vc.c].into_iter().zip(numeric) {
                    let err = max_abs(analytic - numeric) / row_scale;
                    worst = worst.max(err);
                    assert!(err < 1e-7, "{kind:?}: analytic {analytic:?} numeric {numeric:?} ({err:e})");
                }
            }
        }
        assert!(worst > 0.0, "the comparison must have compared something");
    }

    /// Snell's law with relative index eta = η_t/η_i; `wi` points away from the surface on `n`'s side.
    fn refract(wi: DVec3, n: DVec3, eta: f64) -> DVec3 {
        let cos_i = wi.dot(n);
        let cos_t = (1.0 - (1.0 - cos_i * cos_i) / (eta * eta)).sqrt();
        -wi / eta + n * (cos_i / eta - cos_t)
    }

    #[test]
    fn mirror_and_snell_configurations_have_zero_half_vector() {
        let mut rng = Sampler::from_seed(12);
        for _ in 0..100 {
            let ng = (DVec3::Z + random_vec(&mut rng) * 0.3).normalize();
            let mut cur = random_vertex(&mut rng, DVec3::ZERO, ng);
            cur.n = ng;
            let wi = loop {
                let d = random_vec(&mut rng).normalize();
                if d.dot(ng) > 0.3 {
                    break d;
                }
            };
            let at = |d: DVec3, dist: f64| LocalGeometry { p: d * dist, ..cur };
            let mirror = 2.0 * wi.dot(ng) * ng - wi;
            let h = half_vector(&at(wi, 2.0), &cur, &at(mirror, 0.7), 1.0).unwrap();
            assert!(h.length() < 1e-12, "reflection {h:?}");
            // Entering glass from outside (η = 1.5), and leaving it: the light path reversed.
            let inside = refract(wi, ng, 1.5);
            let h = half_vector(&at(wi, 1.3), &cur, &at(inside, 0.4), 1.5).unwrap();
            assert!(h.length() < 1e-12, "refraction in {h:?}");
            let h = half_vector(&at(inside, 0.4), &cur, &at(wi, 1.3), 1.5).unwrap();
            assert!(h.length() < 1e-12, "refraction out {h:?}");
            // A direction that is not the refracted one is off the manifold.
            let wrong = refract(wi, ng, 1.2);
            assert!(half_vector(&at(wi, 1.3), &cur, &at(wrong, 0.4), 1.5).unwrap().length() > 1e-3);
        }
    }

    #[test]
    fn straight_through_an_index_matched_interface_is_the_solution() {
        let cur = random_vertex(&mut Sampler::from_seed(13), DVec3::ZERO, DVec3::Z);
        let w = DVec3::new(0.3, -0.2, 0.9).normalize();
        let at = |d: DVec3| LocalGeometry { p: d, ..cur };
        let vc = half_vector_constraint(&at(w * 2.0), &cur, &at(-w * 0.5), 1.0).unwrap();
        assert!(vc.index_matched && vc.h.length() < 1e-15, "{vc:?}");
        // It stays solvable there: B is invertible although H~ = 0.
        assert!(vc.b.determinant().abs() > 1e-3);
    }

    #[test]
    fn degenerate_segments_and_half_vectors_are_errors() {
        let cur = random_vertex(&mut Sampler::from_seed(14), DVec3::ZERO, DVec3::Z);
        let at = |p: DVec3| LocalGeometry { p, ..cur };
        let e = half_vector(&at(DVec3::ZERO), &cur, &at(DVec3::Z), 1.0).unwrap_err();
        assert!(matches!(e, ConstraintError::DegenerateSegment { .. }));
        let e = half_vector(&at(DVec3::NAN), &cur, &at(DVec3::Z), 1.0).unwrap_err();
        assert!(matches!(e, ConstraintError::DegenerateSegment { .. }));
        // Unit wi and wo cancel only for eta_rel = 1, i.e. index-matched; an eta just outside the
        // index-match tolerance leaves |H~| ~ 1e-9, which must be refused rather than normalised.
        let e = half_vector(&at(DVec3::Z), &cur, &at(-DVec3::Z * 3.0), 1.0 + 1.5e-9).unwrap_err();
        assert!(matches!(e, ConstraintError::DegenerateHalfVector { .. }), "{e:?}");
        // Errors of a path name the vertex.
        let g = [at(DVec3::Z), cur, at(DVec3::new(1.0, 0.0, 1.0)), at(DVec3::new(1.0, 0.0, 1.0))];
        let e = path_constraints(&g, &[1.0; 4]).unwrap_err();
        assert_eq!(e, ConstraintError::DegenerateSegment { vertex: 2 });
    }

    fn vertex_with(p: Vec3, n: Vec3, ng: Vec3, derivatives: SurfaceDerivatives) -> Vertex {
        Vertex {
            kind: VertexKind::Surface,
            p,
            ng,
            frame: Frame::from_normal_tangent(n, derivatives.dpdu),
            uv: Vec2::ZERO,
            derivatives,
            shape: 0,
            prim: 0,
            bary: Vec2::ZERO,
            light: None,
            class: ScatterClass::Glossy { alpha: 0.1 },
            delta: false,
            smooth: true,
            pdf_from_camera: 0.0,
            pdf_from_light: 0.0,
            beta: Spectrum::ONE,
            eps: 1e-4,
        }
    }

    #[test]
    fn from_vertex_orthonormalises_tangents_and_maps_normal_derivatives_alike() {
        let mut rng = Sampler::from_seed(15);
        for _ in 0..50 {
            let ng = (DVec3::Z + random_vec(&mut rng) * 0.3).normalize();
            let n = (ng + random_vec(&mut rng) * 0.1).normalize();
            let in_plane = |rng: &mut Sampler| {
                let v = random_vec(rng);
                (v - ng * ng.dot(v)) * uniform(rng, 0.1, 5.0)
            };
            let (dpdu, dpdv) = (in_plane(&mut rng), in_plane(&mut rng));
            let tangent_n = |rng: &mut Sampler| {
                let v = random_vec(rng);
                v - n * n.dot(v)
            };
            let (dndu, dndv) = (tangent_n(&mut rng), tangent_n(&mut rng));
            let d = SurfaceDerivatives {
                dpdu: dpdu.as_vec3(),
                dpdv: dpdv.as_vec3(),
                dndu: dndu.as_vec3(),
                dndv: dndv.as_vec3(),
                from_uv: true,
            };
            let v = vertex_with(Vec3::ONE, n.as_vec3(), ng.as_vec3(), d);
            let g = LocalGeometry::from_vertex(&v);
            assert!((g.tu.length() - 1.0).abs() < 1e-12 && (g.tv.length() - 1.0).abs() < 1e-12);
            assert!(g.tu.dot(g.tv).abs() < 1e-12);
            // A tangent offset (a, b) is the parameter step (du, dv) with dpdu du + dpdv dv = a tu + b tv;
            // the normal must then change by dndu du + dndv dv (computed in f32 inputs: 1e-5 slack).
            let (a, b) = (uniform(&mut rng, -1.0, 1.0), uniform(&mut rng, -1.0, 1.0));
            let target = g.displacement(DVec2::new(a, b));
            let m = DMat2::from_cols(
                DVec2::new(d.dpdu.as_dvec3().dot(g.tu), d.dpdu.as_dvec3().dot(g.tv)),
                DVec2::new(d.dpdv.as_dvec3().dot(g.tu), d.dpdv.as_dvec3().dot(g.tv)),
            );
            let duv = m.inverse() * DVec2::new(target.dot(g.tu), target.dot(g.tv));
            let dn_param = d.dndu.as_dvec3() * duv.x + d.dndv.as_dvec3() * duv.y;
            let dn_model = g.dn_du * a + g.dn_dv * b;
            let tangential = |w: DVec3| w - g.n * g.n.dot(w);
            assert!((tangential(dn_param) - dn_model).length() < 1e-5 * (1.0 + dn_model.length()));
            // The projection frame follows the normal, not the parameterisation.
            let (s, t) = g.shading_frame().unwrap();
            let r = normal_frame_reference(g.n);
            assert!(
                (s - (r - g.n * r.dot(g.n)).normalize()).length() < 1e-12
                    && (t - g.n.cross(s)).length() < 1e-12
            );
        }
    }

    #[test]
    fn path_constraints_assemble_the_per_vertex_blocks() {
        let mut rng = Sampler::from_seed(16);
        let k = 6;
        let geometry: Vec<LocalGeometry> = (0..=k)
            .map(|i| {
                let p = DVec3::new(i as f64, if i % 2 == 0 { 0.0 } else { 1.0 }, 0.1 * i as f64);
                let ng = DVec3::new(0.0, if i % 2 == 0 { 1.0 } else { -1.0 }, 0.0);
                random_vertex(&mut rng, p, ng)
            })
            .collect();
        let eta = vec![1.0; k + 1];
        let pc = path_constraints(&geometry, &eta).unwrap();
        assert_eq!(pc.h.len(), k - 1);
        assert_eq!(pc.h, path_half_vectors(&geometry, &eta).unwrap());
        for i in 1..k {
            let vc = half_vector_constraint(&geometry[i - 1], &geometry[i], &geometry[i + 1], 1.0).unwrap();
            assert_eq!(
                (pc.jacobian.a[i - 1], pc.jacobian.b[i - 1], pc.jacobian.c[i - 1]),
                (vc.a, vc.b, vc.c)
            );
        }
        // det J against a finite-difference Jacobian of all half vectors w.r.t. all inner offsets.
        let n = k - 1;
        let step = 1e-6;
        let mut dense = nalgebra::DMatrix::<f64>::zeros(2 * n, 2 * n);
        for j in 0..n {
            for axis in 0..2 {
                let d = if axis == 0 { DVec2::X * step } else { DVec2::Y * step };
                let eval = |sign: f64| {
                    let mut g = geometry.clone();
                    g[j + 1] = g[j + 1].offset(d * sign);
                    path_half_vectors(&g, &eta).unwrap()
                };
                let (hp, hm) = (eval(1.0), eval(-1.0));
                for i in 0..n {
                    let col = (hp[i] - hm[i]) / (2.0 * step);
                    dense[(2 * i, 2 * j + axis)] = col.x;
                    dense[(2 * i + 1, 2 * j + axis)] = col.y;
                }
            }
        }
        let det_fd = dense.determinant();
        let det = pc.jacobian.factor().unwrap().log_det().value();
        assert!(((det - det_fd) / det_fd).abs() < 1e-6, "det J {det:e} vs finite differences {det_fd:e}");
    }
}
