//! Surface interactions: the local geometry at a ray hit (position, geometric normal, a continuous
//! shading frame from interpolated normals with the tangent aligned to ∂p/∂u, texture coordinates).

use super::Scene;
use crate::accel::Hit;
use crate::geometry::{Frame, Ray, Vec2, Vec3};
use crate::lights::SurfacePoint;

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
    /// Barycentric coordinates (b1, b2) of `p` in triangle `prim`.
    pub bary: Vec2,
    /// How far rays leaving `p` start off the surface (`geometry::ray_epsilon`).
    pub eps: f32,
}

/// First-order surface geometry at a point: how position and shading normal change with the surface
/// parameters (u, v). These come from the texture coordinates where the mesh has them, otherwise from
/// the barycentric coordinates of the triangle (so they are only continuous within one triangle).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceDerivatives {
    pub dpdu: Vec3,
    pub dpdv: Vec3,
    /// Derivatives of the unit shading normal (zero on flat-shaded triangles).
    pub dndu: Vec3,
    pub dndv: Vec3,
    /// True when (u, v) are the mesh's texture coordinates (continuous across triangles).
    pub from_uv: bool,
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
        let eps = crate::geometry::ray_epsilon(p, p0.abs().max(p1.abs()).max(p2.abs()).max_element());
        Some(SurfaceInteraction { p, t: hit.t, ng, frame, uv, wi, shape, prim, bary: Vec2::new(b1, b2), eps })
    }

    /// The derivatives of position and shading normal at this point (pbrt-v4's triangle differentials:
    /// solve the 2×2 system relating edge vectors to parameter differences).
    pub fn derivatives(&self, scene: &Scene) -> SurfaceDerivatives {
        surface_derivatives(&scene.shapes[self.shape].mesh, self.prim, self.bary)
    }

    /// Spawns a ray leaving the surface in world direction `dir` (`Ray::leaving`).
    pub fn spawn_ray(&self, dir: Vec3) -> Ray {
        Ray::leaving(self.p, dir, self.eps)
    }

    /// The offset of shadow rays leaving `p` (`geometry::offset_origin`).
    pub fn offset(&self) -> Vec3 {
        self.ng * self.eps
    }

    /// The emitter-side description of this hit, for when its shape is an area light.
    pub fn light_point(&self) -> SurfacePoint {
        SurfacePoint {
            prim: self.prim,
            bary: self.bary,
            p: self.p,
            ng: self.ng,
            ns: self.frame.n,
            uv: self.uv,
        }
    }
}

/// Position and shading-normal derivatives of `mesh` at barycentrics `bary` of triangle `prim`.
pub fn surface_derivatives(
    mesh: &crate::geometry::TriangleMesh,
    prim: usize,
    bary: Vec2,
) -> SurfaceDerivatives {
    let [i0, i1, i2] = mesh.indices[prim].map(|i| i as usize);
    let (p0, p1, p2) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
    let (e1, e2) = (p1 - p0, p2 - p0);
    // Parameter differences along the two edges: texture coordinates, or the barycentric axes.
    let uv_param = mesh.uvs.as_ref().and_then(|t| {
        let (d1, d2) = (t[i1] - t[i0], t[i2] - t[i0]);
        let det = d1.x * d2.y - d1.y * d2.x;
        (det.abs() > 1e-12 * (d1.length_squared() + d2.length_squared()).max(1e-30)).then_some((d1, d2, det))
    });
    // Solves [e1 e2] = [dX/du dX/dv] [d1 d2] for dX/du, dX/dv.
    let solve = |f1: Vec3, f2: Vec3| -> (Vec3, Vec3) {
        match uv_param {
            Some((d1, d2, det)) => ((f1 * d2.y - f2 * d1.y) / det, (f2 * d1.x - f1 * d2.x) / det),
            None => (f1, f2),
        }
    };
    let (dpdu, dpdv) = solve(e1, e2);
    let (dndu, dndv) = match &mesh.normals {
        Some(n) => {
            let b0 = 1.0 - bary.x - bary.y;
            let raw = n[i0] * b0 + n[i1] * bary.x + n[i2] * bary.y;
            let len = raw.length();
            if len > 1e-12 {
                let unit = raw / len;
                // d(n/|n|) = (I − n̂ n̂ᵀ) dn / |n|
                let project = |d: Vec3| (d - unit * unit.dot(d)) / len;
                let (du, dv) = solve(n[i1] - n[i0], n[i2] - n[i0]);
                (project(du), project(dv))
            } else {
                (Vec3::ZERO, Vec3::ZERO)
            }
        }
        None => (Vec3::ZERO, Vec3::ZERO),
    };
    SurfaceDerivatives { dpdu, dpdv, dndu, dndv, from_uv: uv_param.is_some() }
}
