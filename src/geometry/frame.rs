//! Orthonormal frames used for local shading coordinates.
//! The basis construction is Duff et al. 2017, "Building an Orthonormal Basis, Revisited", which is
//! continuous except at n.z = -1 and free of the precision loss of the older Frisvad method.

use glam::Vec3;

/// Orthonormal frame: `s`, `t` tangents and normal `n` (local +z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub s: Vec3,
    pub t: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// Builds a frame around a unit normal.
    pub fn from_normal(n: Vec3) -> Frame {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }

    /// Builds a frame from a normal and a preferred tangent direction (Gram-Schmidt); falls back to
    /// `from_normal` when the tangent is degenerate or parallel to the normal.
    pub fn from_normal_tangent(n: Vec3, tangent: Vec3) -> Frame {
        let s = tangent - n * n.dot(tangent);
        let len2 = s.length_squared();
        if !len2.is_finite() || len2 <= 1e-12 {
            return Frame::from_normal(n);
        }
        let s = s / len2.sqrt();
        Frame { s, t: n.cross(s), n }
    }

    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal_and_invert() {
        let normals = [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.4, 0.866).normalize(),
            Vec3::new(1e-7, 0.0, -1.0).normalize(),
        ];
        for n in normals {
            let f = Frame::from_normal(n);
            assert!((f.s.length() - 1.0).abs() < 1e-5, "{n:?}");
            assert!((f.t.length() - 1.0).abs() < 1e-5, "{n:?}");
            assert!(f.s.dot(f.t).abs() < 1e-5 && f.s.dot(n).abs() < 1e-5 && f.t.dot(n).abs() < 1e-5);
            let v = Vec3::new(0.2, -0.7, 0.4);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        }
    }
}
