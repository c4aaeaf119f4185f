//! The generalised half-vector constraint of an inner path vertex (HSLT, Kaplanyan et al. 2014, Sec. 4;
//! Walter et al. 2007 for refraction) and its analytic derivative blocks A_i, B_i, C_i with respect to
//! the tangent-plane offsets of x_{i-1}, x_i, x_{i+1} (appendix Eq. 11), assembled into J for a path.

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
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalGeometry {
    pub p: DVec3,
    pub ng: DVec3,
    pub n: DVec3,
    pub tu: DVec3,
    pub tv: DVec3,
    pub dn_du: DVec3,
    pub dn_dv: DVec3,
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
        if !dn_du.is_finite() || !dn_dv.is_finite() {
            return LocalGeometry { tu, tv, ..fallback };
        }
        LocalGeometry { p: dvec3(v.p), ng, n, tu, tv, dn_du, dn_dv }
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

    /// The orthonormal shading frame (s, t, n) in which half vectors are projected: s is tu made
    /// orthogonal to n, t = n × s. For a surface vertex this is the vertex's own `Frame`.
    pub fn shading_frame(&self) -> Option<(DVec3, DVec3)> {
        let s = (self.tu - self.n * self.tu.dot(self.n)).try_normalize()?;
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
        let s_raw = cur.tu - cur.n * cur.tu.dot(cur.n);
        let s_len = s_raw.length();
        let ds_raw = -cur.n * cur.tu.dot(dn) - dn * cur.tu.dot(cur.n);
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
    assert_eq!(geometry.len(), eta.len(), "one eta per path vertex");
    (1..geometry.len().saturating_sub(1))
        .map(|i| {
            half_vector(&geometry[i - 1], &geometry[i], &geometry[i + 1], eta[i])
                .map_err(|e| with_vertex(e, i))
        })
        .collect()
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

/// The eta of each path vertex's BSDF (1 for endpoints and non-refracting BSDFs).
pub fn path_etas(scene: &Scene, path: &[Vertex]) -> Vec<f64> {
    path.iter().map(|v| v.bsdf(scene).map_or(1.0, |b| b.eta() as f64)).collect()
}
