//! Diffuse area emitter on a triangle mesh (Mitsuba's `area`): constant or textured radiance, emitted
//! on the front side of the shading normal only. Points are sampled uniformly by area (triangle picked
//! in proportion to its area), and densities converted to solid angle with the geometric normal.

use super::{check_emission, LightSample};
use crate::geometry::TriangleMesh;
use crate::props::{Props, SceneError};
use crate::sampling::{square_to_uniform_triangle, Distribution1D};
use crate::spectrum::{luminance, Spectrum};
use crate::texture::Texture;
use glam::{Vec2, Vec3};
use std::sync::Arc;

#[derive(Debug)]
pub struct AreaLight {
    pub mesh: Arc<TriangleMesh>,
    /// Index of the emitting shape in the scene.
    pub shape: usize,
    pub radiance: Texture,
    triangles: Distribution1D,
    total_area: f32,
    /// Per triangle: the geometric normal, and the shading normal where it is the same over the
    /// whole triangle (no vertex normals, or three equal ones). Light sampling builds a surface
    /// point per shadow ray, and recomputing these there was a tenth of a path tracer's time.
    triangle_normals: Vec<(Vec3, Option<Vec3>)>,
}

/// A point on an emitter with what is needed to evaluate emission there.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// Triangle of the emitting mesh and barycentrics (b1, b2) in it.
    pub prim: usize,
    pub bary: Vec2,
    pub p: Vec3,
    pub ng: Vec3,
    pub ns: Vec3,
    pub uv: Vec2,
}

impl AreaLight {
    pub fn from_props(props: &Props, mesh: Arc<TriangleMesh>, shape: usize) -> Result<AreaLight, SceneError> {
        props.expect_only(&["radiance"], &["texture"])?;
        let radiance = Texture::from_param(props, "radiance", Vec3::ONE)?;
        check_emission(props, "radiance", radiance.mean())?;
        let areas: Vec<f64> = (0..mesh.triangle_count()).map(|i| mesh.area(i) as f64).collect();
        let triangles = Distribution1D::new(&areas)
            .ok_or_else(|| props.error(format!("the emitting shape '{}' has zero area", mesh.name)))?;
        let total_area = triangles.total() as f32;
        let triangle_normals =
            (0..mesh.triangle_count()).map(|tri| Self::triangle_normals(&mesh, tri)).collect();
        Ok(AreaLight { mesh, shape, radiance, triangles, total_area, triangle_normals })
    }

    fn triangle_normals(mesh: &TriangleMesh, tri: usize) -> (Vec3, Option<Vec3>) {
        let ng = mesh.geometric_normal(tri);
        let flat = match &mesh.normals {
            None => Some(ng),
            Some(n) => {
                let [i0, i1, i2] = mesh.indices[tri].map(|i| n[i as usize]);
                (i0 == i1 && i1 == i2).then(|| i0.try_normalize().unwrap_or(ng))
            }
        };
        (ng, flat)
    }

    pub fn total_area(&self) -> f32 {
        self.total_area
    }

    /// Density of a point per unit area (uniform over the surface).
    pub fn pdf_area(&self) -> f32 {
        1.0 / self.total_area
    }

    /// Radiance leaving point `sp` in direction `w` (pointing away from the surface).
    pub fn emitted(&self, sp: &SurfacePoint, w: Vec3) -> Spectrum {
        if sp.ns.dot(w) <= 0.0 {
            return Spectrum::ZERO;
        }
        self.radiance.eval(sp.uv)
    }

    /// Uniformly samples a point on the surface.
    pub fn sample_point(&self, u: Vec2) -> SurfacePoint {
        let (tri, ux) = self.triangles.sample(u.x);
        let b = square_to_uniform_triangle(Vec2::new(ux, u.y));
        self.mesh_point(tri, b)
    }

    /// Surface point at barycentrics `b` = (b1, b2) of triangle `tri`.
    pub fn mesh_point(&self, tri: usize, b: Vec2) -> SurfacePoint {
        let m = &self.mesh;
        let [i0, i1, i2] = m.indices[tri].map(|i| i as usize);
        let b0 = 1.0 - b.x - b.y;
        let p = m.positions[i0] * b0 + m.positions[i1] * b.x + m.positions[i2] * b.y;
        let (ng, flat) = self.triangle_normals[tri];
        // `flat` is None only for a triangle whose vertex normals differ.
        let ns = flat.unwrap_or_else(|| match &m.normals {
            Some(n) => (n[i0] * b0 + n[i1] * b.x + n[i2] * b.y).try_normalize().unwrap_or(ng),
            None => ng,
        });
        let uv = match &m.uvs {
            Some(t) => t[i0] * b0 + t[i1] * b.x + t[i2] * b.y,
            None => b,
        };
        SurfacePoint { prim: tri, bary: b, p, ng, ns, uv }
    }

    pub fn sample_li(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        let sp = self.sample_point(u);
        let d = sp.p - p;
        let dist2 = d.length_squared();
        if !(dist2 > 0.0) || !dist2.is_finite() {
            return None;
        }
        let dist = dist2.sqrt();
        let wi = d / dist;
        let cos_light = sp.ng.dot(-wi).abs();
        if cos_light <= 1e-7 {
            return None;
        }
        let radiance = self.emitted(&sp, -wi);
        if radiance == Spectrum::ZERO {
            return None;
        }
        let pdf = self.pdf_area() * dist2 / cos_light;
        pdf.is_finite().then_some(LightSample { p: sp.p, wi, dist, radiance, pdf, is_delta: false })
    }

    /// Solid-angle density of `sample_li` choosing light point `q` (geometric normal `ng`) from `p`.
    pub fn pdf_li(&self, p: Vec3, q: Vec3, ng: Vec3) -> f32 {
        let d = q - p;
        let dist2 = d.length_squared();
        let cos_light = ng.dot(d).abs() / dist2.sqrt();
        if cos_light <= 1e-7 {
            return 0.0;
        }
        self.pdf_area() * dist2 / cos_light
    }

    /// Geometric normal turned to the emitting side (the side of the shading normal).
    pub fn emitting_normal(sp: &SurfacePoint) -> Vec3 {
        if sp.ng.dot(sp.ns) < 0.0 {
            -sp.ng
        } else {
            sp.ng
        }
    }

    pub fn power(&self) -> f32 {
        std::f32::consts::PI * self.total_area * luminance(self.radiance.mean())
    }
}
