//! Affine transforms with their cached inverse, applied to points, vectors and normals
//! (normals use the inverse transpose so they stay perpendicular under non-uniform scale).

use glam::{Mat4, Vec3};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub matrix: Mat4,
    pub inverse: Mat4,
}

impl Default for Transform {
    fn default() -> Self {
        Transform { matrix: Mat4::IDENTITY, inverse: Mat4::IDENTITY }
    }
}

impl Transform {
    /// Returns `None` when the matrix is singular or not finite.
    pub fn new(matrix: Mat4) -> Option<Transform> {
        let det = matrix.determinant();
        if !det.is_finite() || det.abs() < 1e-30 {
            return None;
        }
        let inverse = matrix.inverse();
        if !inverse.is_finite() {
            return None;
        }
        Some(Transform { matrix, inverse })
    }

    /// Transforms a point with Mitsuba 3's arithmetic (`transform_affine`: the translation column,
    /// then one fused multiply-add per coordinate), so that mesh vertices land on the same floats in
    /// both renderers and coplanar faces round alike (docs/rough-glass.md).
    pub fn point(&self, p: Vec3) -> Vec3 {
        let fma = |col: usize, s: f32, acc: Vec3| {
            let c = self.matrix.col(col).truncate();
            Vec3::new(c.x.mul_add(s, acc.x), c.y.mul_add(s, acc.y), c.z.mul_add(s, acc.z))
        };
        fma(2, p.z, fma(1, p.y, fma(0, p.x, self.matrix.col(3).truncate())))
    }

    pub fn vector(&self, v: Vec3) -> Vec3 {
        self.matrix.transform_vector3(v)
    }

    /// Transforms a normal (not normalised).
    pub fn normal(&self, n: Vec3) -> Vec3 {
        self.inverse.transpose().transform_vector3(n)
    }

    /// True when the transform flips handedness (negative determinant), which flips triangle winding.
    pub fn flips_handedness(&self) -> bool {
        self.matrix.determinant() < 0.0
    }
}
