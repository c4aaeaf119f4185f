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

    pub fn point(&self, p: Vec3) -> Vec3 {
        self.matrix.transform_point3(p)
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
