//! Surface interactions: the local geometry at a ray hit (position, geometric normal, a continuous
//! shading frame from interpolated normals with the tangent aligned to ∂p/∂u, texture coordinates).

use super::Scene;
use crate::accel::Hit;
use crate::geometry::{Frame, Ray, Vec2, Vec3};

#[derive(Clone, Copy, Debug)]
pub struct SurfaceInteraction {
    pub p: Vec3,
    pub t: f32,
    /// Geometric normal, oriented by the triangle winding (not towards the ray).
    pub ng: Vec3,
    /// Shading frame (interpolated normal when the mesh has one, else the geometric normal).
    pub frame: Frame,
    pub uv: Vec2,
    /// Unit direction back towards the ray origin.
    pub wi: Vec3,
    pub shape: usize,
    pub prim: usize,
}

impl SurfaceInteraction {
    pub fn from_hit(scene: &Scene, ray: &Ray, hit: &Hit) -> Option<SurfaceInteraction> {
        let shape = hit.geom_id as usize;
        let prim = hit.prim_id as usize;
        let mesh = &scene.shapes.get(shape)?.mesh;
        if prim >= mesh.indices.len() {
            return None;
        }
        let [i0, i1, i2] = mesh.indices[prim].map(|i| i as usize);
        let (p0, p1, p2) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
        let (b1, b2) = (hit.u, hit.v);
        let b0 = 1.0 - b1 - b2;
        // Interpolating the vertices is more precise than origin + t·dir far from the origin.
        let p = p0 * b0 + p1 * b1 + p2 * b2;
        let ng = (p1 - p0).cross(p2 - p0).try_normalize()?;
        let uvs = mesh.uvs.as_ref().map(|t| (t[i0], t[i1], t[i2]));
        let uv = match uvs {
            Some((t0, t1, t2)) => t0 * b0 + t1 * b1 + t2 * b2,
            None => Vec2::new(b1, b2),
        };
        let ns = match &mesh.normals {
            Some(n) => {
                let ns = (n[i0] * b0 + n[i1] * b1 + n[i2] * b2).try_normalize().unwrap_or(ng);
                if ns.is_finite() {
                    ns
                } else {
                    ng
                }
            }
            None => ng,
        };
        let dpdu = uvs.and_then(|(t0, t1, t2)| {
            let (d1, d2) = (t1 - t0, t2 - t0);
            let det = d1.x * d2.y - d1.y * d2.x;
            if det.abs() < 1e-12 {
                return None;
            }
            let dpdu = ((p1 - p0) * d2.y - (p2 - p0) * d1.y) / det;
            dpdu.is_finite().then_some(dpdu)
        });
        let tangent = dpdu.unwrap_or(p1 - p0);
        let frame = Frame::from_normal_tangent(ns, tangent);
        let wi = -ray.dir;
        Some(SurfaceInteraction { p, t: hit.t, ng, frame, uv, wi, shape, prim })
    }

    /// Spawns a ray leaving the surface in world direction `dir`, offset off the surface on its side.
    pub fn spawn_ray(&self, dir: Vec3) -> Ray {
        Ray::new(crate::geometry::offset_origin(self.p, self.ng, dir), dir)
    }
}
