//! World-space triangle meshes: the single geometric primitive handed to the ray-query backends.
//! Analytic shapes (rectangle, cube, disk, sphere) are tessellated on load with smooth normals and UVs
//! kept, because the manifold walk needs continuous shading frames.

use super::{Bounds3, Vec2, Vec3};

#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Name for messages (the shape's id, or the file name).
    pub name: String,
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (unit length), if the shape has smooth shading.
    pub normals: Option<Vec<Vec3>>,
    /// Per-vertex texture coordinates.
    pub uvs: Option<Vec<Vec2>>,
    pub indices: Vec<[u32; 3]>,
}

impl TriangleMesh {
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    pub fn vertices(&self, prim: usize) -> [Vec3; 3] {
        let [a, b, c] = self.indices[prim];
        [self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]]
    }

    /// The largest absolute coordinate of triangle `prim`'s vertices: the scale of the rounding
    /// error of a ray hit on it (see `ray_epsilon`).
    pub fn coordinate_scale(&self, prim: usize) -> f32 {
        let [a, b, c] = self.vertices(prim);
        a.abs().max(b.abs()).max(c.abs()).max_element()
    }

    pub fn area(&self, prim: usize) -> f32 {
        let [a, b, c] = self.vertices(prim);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Unit geometric normal, oriented by the winding (counter-clockwise is front).
    pub fn geometric_normal(&self, prim: usize) -> Vec3 {
        let [a, b, c] = self.vertices(prim);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// How the mesh is named in messages: `mesh #3 'Floor'`.
    pub fn label(&self, index: usize) -> String {
        if self.name.is_empty() {
            format!("mesh #{index}")
        } else {
            format!("mesh #{index} '{}'", self.name)
        }
    }

    /// Checks what every ray-query backend relies on: finite vertices, indices in range and counts
    /// that fit 32-bit ids. The message names the mesh (as mesh number `index`) and the element.
    pub fn validate(&self, index: usize) -> Result<(), String> {
        if self.positions.len() > u32::MAX as usize || self.indices.len() > u32::MAX as usize {
            return Err(format!(
                "{} has {} vertices and {} triangles; at most 2^32-1 of each are supported",
                self.label(index),
                self.positions.len(),
                self.indices.len()
            ));
        }
        if let Some((v, p)) = self.positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(format!(
                "{} vertex {v} has a non-finite position ({}, {}, {}); expected finite coordinates",
                self.label(index),
                p.x,
                p.y,
                p.z
            ));
        }
        let vertex_count = self.positions.len();
        for (t, tri) in self.indices.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i as usize >= vertex_count) {
                return Err(format!(
                    "{} triangle {t} uses vertex index {bad}, but the mesh has {vertex_count} vertices",
                    self.label(index)
                ));
            }
        }
        Ok(())
    }

    pub fn bounds(&self) -> Bounds3 {
        let mut b = Bounds3::default();
        for &p in &self.positions {
            b.expand(p);
        }
        b
    }
}
