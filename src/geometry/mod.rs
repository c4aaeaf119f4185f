//! Geometry and frames: rays, orthonormal shading frames, affine transforms and triangle meshes.
//! Every other module works in world space with these types; local shading-frame
//! coordinates follow the usual convention that the normal is +z (pbrt-v4 §2.5, Mitsuba's `Frame3f`).

mod frame;
mod mesh;
mod transform;

pub use frame::Frame;
pub use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};
pub use mesh::TriangleMesh;
pub use transform::Transform;

/// A ray with a parametric validity interval `(tmin, tmax)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub tmin: f32,
    pub tmax: f32,
}

impl Ray {
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir, tmin: 0.0, tmax: f32::INFINITY }
    }

    pub fn segment(origin: Vec3, dir: Vec3, tmax: f32) -> Self {
        Ray { origin, dir, tmin: 0.0, tmax }
    }

    /// A ray leaving the surface point `p` along the unit direction `dir`, on the exact line through
    /// `p`: the surface is skipped by starting at t = `eps` (the point's `ray_epsilon`) instead of
    /// moving the origin off it. Path densities are recomputed from vertex positions (`PathView::density`), and a vertex
    /// found from a displaced origin lies off the line p + t·dir: over a short edge (a glass block
    /// 2e-3 above a floor) the direction between the two positions then misses the sampled one by
    /// ε/length, several lobe widths of a near-specular BSDF, and BDPT's MIS weights go wrong.
    pub fn leaving(p: Vec3, dir: Vec3, eps: f32) -> Self {
        Ray { origin: p, dir, tmin: eps, tmax: f32::INFINITY }
    }

    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds3 {
    pub min: Vec3,
    pub max: Vec3,
}

impl Default for Bounds3 {
    fn default() -> Self {
        Bounds3 { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) }
    }
}

impl Bounds3 {
    pub fn expand(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    pub fn union(&self, other: &Bounds3) -> Bounds3 {
        Bounds3 { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Radius of the bounding sphere centred at `center()`.
    pub fn radius(&self) -> f32 {
        if self.is_empty() {
            0.0
        } else {
            (self.max - self.min).length() * 0.5
        }
    }
}

/// How far a ray leaving a surface point `p` must start from it to miss the surface it leaves:
/// 1e-4 of the larger of |p| and `scale`, the largest coordinate of the triangle `p` lies on (the
/// rounding of the triangle test grows with both). Purely relative, so a scene scaled by 1e-3 or 1e3
/// renders the same image: an absolute floor (1e-4 scene units before) was 2.5% of the size of the
/// stability case 13 scene at 1e-3 and darkened it by 2-8% (docs/stability.md).
pub fn ray_epsilon(p: Vec3, scale: f32) -> f32 {
    p.abs().max_element().max(scale) * 1e-4
}

/// Moves `p` off its surface by `offset` (the geometric normal times the point's `ray_epsilon`, or
/// zero for points that are not on a surface), to the side that `dir` points into.
pub fn offset_origin(p: Vec3, offset: Vec3, dir: Vec3) -> Vec3 {
    if offset.dot(dir) >= 0.0 {
        p + offset
    } else {
        p - offset
    }
}

/// Reflects `wi` about `n` (both pointing away from the surface).
pub fn reflect(wi: Vec3, n: Vec3) -> Vec3 {
    2.0 * wi.dot(n) * n - wi
}

/// Refracts `wi` (pointing away from the surface, on the side of `n` when `cos_i > 0`) through an interface
/// with relative index `eta = eta_transmitted / eta_incident`. Returns `None` on total internal reflection.
pub fn refract(wi: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = wi.dot(n);
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let sign = if cos_i >= 0.0 { 1.0 } else { -1.0 };
    Some(-wi / eta + (cos_i / eta - sign * cos_t) * n)
}
