//! Tessellations of Mitsuba's analytic shapes in object space, with the uv parameterisations of
//! Mitsuba 3 (`rectangle.cpp`, `cube.cpp`, `disk.cpp`, `sphere.cpp`) and analytic smooth normals.

use super::RawMesh;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Sphere latitude rings (θ steps) and longitude segments (φ steps). With 64 × 128 the inscribed
/// polyhedron's area is within 1e-3 (relative) of 4πr² (inscribed area is 5.0e-4 below 4πr²; tests check it).
pub const SPHERE_THETA_RINGS: u32 = 64;
pub const SPHERE_PHI_SEGMENTS: u32 = 128;
/// Disk rim segments: the inscribed 256-gon has area π(1 − 1e-4).
const DISK_SEGMENTS: u32 = 256;

pub fn sphere_resolution() -> (u32, u32) {
    (SPHERE_THETA_RINGS, SPHERE_PHI_SEGMENTS)
}

/// [-1, 1]² at z = 0, normal +z, uv = ((x + 1)/2, (y + 1)/2): Mitsuba 3's rectangle mesh, vertex
/// for vertex and triangle for triangle. The order matters where the rectangle is coplanar with other
/// geometry (a floor under a cube resting on it): which of two coincident faces a ray meets first is
/// then decided by rounding in the triangle test, and the same triangles round the same way in
/// Embree for both renderers (docs/rough-glass.md).
pub(super) fn rectangle() -> RawMesh {
    let corners = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)];
    RawMesh {
        positions: corners.iter().map(|&(x, y)| Vec3::new(x, y, 0.0)).collect(),
        normals: Some(vec![Vec3::Z; 4]),
        uvs: Some(corners.iter().map(|&(x, y)| Vec2::new((x + 1.0) * 0.5, (y + 1.0) * 0.5)).collect()),
        indices: vec![[1, 2, 0], [1, 3, 2]],
    }
}

/// [-1, 1]³ with 4 vertices per face (so normals stay per face), outward normals, and every face
/// mapped onto [0, 1]² in uv: Mitsuba 3's `cube.cpp` tables, in its order (see `rectangle`).
pub(super) fn cube() -> RawMesh {
    const P: [[f32; 3]; 24] = [
        [1.0, -1.0, -1.0],
        [1.0, -1.0, 1.0],
        [-1.0, -1.0, 1.0],
        [-1.0, -1.0, -1.0],
        [1.0, 1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, 1.0, 1.0],
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [1.0, 1.0, -1.0],
        [1.0, 1.0, 1.0],
        [1.0, -1.0, 1.0],
        [1.0, -1.0, 1.0],
        [1.0, 1.0, 1.0],
        [-1.0, 1.0, 1.0],
        [-1.0, -1.0, 1.0],
        [-1.0, -1.0, 1.0],
        [-1.0, 1.0, 1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, -1.0],
        [1.0, 1.0, -1.0],
        [1.0, -1.0, -1.0],
        [-1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
    ];
    const FACE_NORMALS: [[f32; 3]; 6] = [
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
    ];
    const FACE_UVS: [[f32; 2]; 4] = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
    let positions = P.iter().map(|&p| Vec3::from(p)).collect();
    let normals = (0..24).map(|i| Vec3::from(FACE_NORMALS[i / 4])).collect();
    let uvs = (0..24).map(|i| Vec2::from(FACE_UVS[i % 4])).collect();
    let indices =
        (0..6u32).flat_map(|f| [[4 * f, 4 * f + 1, 4 * f + 2], [4 * f + 3, 4 * f, 4 * f + 2]]).collect();
    RawMesh { positions, normals: Some(normals), uvs: Some(uvs), indices }
}

/// Unit disk at z = 0, normal +z, uv = (r, φ/2π). The centre is repeated per segment so that each
/// fan triangle interpolates φ without wrapping.
pub(super) fn disk() -> RawMesh {
    let n = DISK_SEGMENTS;
    let mut m = RawMesh { normals: Some(Vec::new()), uvs: Some(Vec::new()), ..Default::default() };
    for j in 0..=n {
        let t = j as f32 / n as f32;
        let phi = 2.0 * PI * t;
        m.positions.push(Vec3::new(phi.cos(), phi.sin(), 0.0));
        m.uvs.as_mut().unwrap().push(Vec2::new(1.0, t));
    }
    let centre0 = m.positions.len() as u32;
    for j in 0..n {
        m.positions.push(Vec3::ZERO);
        m.uvs.as_mut().unwrap().push(Vec2::new(0.0, (j as f32 + 0.5) / n as f32));
        m.indices.push([centre0 + j, j, j + 1]);
    }
    m.normals = Some(vec![Vec3::Z; m.positions.len()]);
    m
}

/// Unit sphere: normals are the analytic ones (the position itself), uv = (φ/2π, θ/π) with θ from
/// +z. Each pole is one vertex per segment (its own u), so cap triangles are never degenerate and
/// the pole normal is exactly ±z.
pub(super) fn sphere() -> RawMesh {
    let (nt, np) = (SPHERE_THETA_RINGS, SPHERE_PHI_SEGMENTS);
    let mut pos = Vec::new();
    let mut uv = Vec::new();
    // Interior rings i = 1..nt-1, each with np + 1 vertices (the seam column is duplicated).
    let ring = |i: u32, j: u32| (i - 1) * (np + 1) + j;
    for i in 1..nt {
        let v = i as f32 / nt as f32;
        let theta = PI * v;
        for j in 0..=np {
            let u = j as f32 / np as f32;
            let phi = 2.0 * PI * u;
            pos.push(Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()));
            uv.push(Vec2::new(u, v));
        }
    }
    let north0 = pos.len() as u32;
    for j in 0..np {
        pos.push(Vec3::Z);
        uv.push(Vec2::new((j as f32 + 0.5) / np as f32, 0.0));
    }
    let south0 = pos.len() as u32;
    for j in 0..np {
        pos.push(-Vec3::Z);
        uv.push(Vec2::new((j as f32 + 0.5) / np as f32, 1.0));
    }
    let mut idx = Vec::new();
    for j in 0..np {
        idx.push([north0 + j, ring(1, j), ring(1, j + 1)]);
        for i in 1..nt - 1 {
            let (a, b) = (ring(i, j), ring(i, j + 1));
            let (c, d) = (ring(i + 1, j), ring(i + 1, j + 1));
            idx.push([a, c, d]);
            idx.push([a, d, b]);
        }
        idx.push([ring(nt - 1, j), south0 + j, ring(nt - 1, j + 1)]);
    }
    RawMesh { normals: Some(pos.clone()), positions: pos, uvs: Some(uv), indices: idx }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_orientation(m: &RawMesh) {
        let ns = m.normals.as_ref().unwrap();
        for tri in &m.indices {
            let [a, b, c] = tri.map(|i| m.positions[i as usize]);
            let ng = (b - a).cross(c - a).normalize();
            for &i in tri {
                assert!(ng.dot(ns[i as usize]) > 0.0, "{tri:?}");
            }
        }
    }

    #[test]
    fn analytic_shapes_wind_with_their_normals() {
        for m in [rectangle(), cube(), disk(), sphere()] {
            check_orientation(&m);
        }
    }

    #[test]
    fn disk_area_is_close_to_pi() {
        let m = disk();
        let area: f32 = m
            .indices
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum();
        assert!((area / PI - 1.0).abs() < 2e-4, "{area}");
    }
}
