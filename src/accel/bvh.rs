//! Pure-Rust ray queries: an eight-wide compressed BVH (Ylitie, Karras, Laine, "Efficient Incoherent
//! Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017) built by the `obvhs` crate (PLOC +
//! reinsertion), with our own watertight ray/triangle test (Woop, Benthin, Wald, JCGT 2013).

use std::borrow::Borrow;

use anyhow::bail;
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;
use obvhs::{Boundable, BvhBuildParams};

use super::{Hit, RayQuery};
use crate::geometry::{Ray, TriangleMesh, Vec3};

/// A triangle in BVH leaf order, carrying the ids the renderer's `Hit` convention needs.
#[derive(Clone, Copy, Debug)]
struct LeafTriangle {
    p0: Vec3,
    p1: Vec3,
    p2: Vec3,
    geom_id: u32,
    prim_id: u32,
}

/// A triangle's bounds as handed to the builder, padded so that the crate's slab test (which has no
/// error bounds of its own) cannot reject a ray that exactly grazes a flat or shared face.
struct PaddedBox(Aabb);

impl Boundable for PaddedBox {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

/// The pure-Rust backend. `Hit::geom_id` is the index of the mesh given to [`BvhScene::build`]
/// (empty meshes keep their index), `prim_id` the triangle within it.
pub struct BvhScene {
    bvh: Option<CwBvh>,
    triangles: Vec<LeafTriangle>,
    mesh_count: usize,
}

impl BvhScene {
    /// Builds the BVH over `meshes` (world space). Fails naming the mesh and element on non-finite
    /// vertices or out-of-range indices.
    /// Takes owned meshes, references or `Arc`s alike, so callers need not copy their meshes.
    pub fn build<M: Borrow<TriangleMesh>>(meshes: &[M]) -> anyhow::Result<BvhScene> {
        if meshes.len() > u32::MAX as usize {
            bail!("BVH: {} meshes exceed the geometry id range", meshes.len());
        }
        let mut triangles = Vec::with_capacity(meshes.iter().map(|m| m.borrow().indices.len()).sum());
        let mut extent = 0.0f32;
        for (geom, mesh) in meshes.iter().enumerate() {
            let mesh = mesh.borrow();
            validate_mesh(geom, mesh)?;
            for (prim, tri) in mesh.indices.iter().enumerate() {
                let [p0, p1, p2] = tri.map(|i| mesh.positions[i as usize]);
                extent = extent
                    .max(p0.abs().max_element())
                    .max(p1.abs().max_element())
                    .max(p2.abs().max_element());
                triangles.push(LeafTriangle { p0, p1, p2, geom_id: geom as u32, prim_id: prim as u32 });
            }
        }
        if triangles.is_empty() {
            return Ok(BvhScene { bvh: None, triangles, mesh_count: meshes.len() });
        }
        // A few hundred ulps of the largest coordinate: far more than the slab test's rounding
        // (a handful of ulps of |box - origin| for origins within the scene's scale), far less than
        // any feature the renderer resolves.
        let pad = Vec3::splat(extent.max(f32::MIN_POSITIVE) * 1e-5);
        let boxes: Vec<PaddedBox> = triangles
            .iter()
            .map(|t| {
                let lo = t.p0.min(t.p1).min(t.p2);
                let hi = t.p0.max(t.p1).max(t.p2);
                PaddedBox(Aabb::new((lo - pad).to_array().into(), (hi + pad).to_array().into()))
            })
            .collect();
        let mut build_time = std::time::Duration::ZERO;
        let bvh = obvhs::cwbvh::builder::build_cwbvh(&boxes, BvhBuildParams::medium_build(), &mut build_time);
        // Store triangles in leaf order so traversal reads them without an index indirection.
        let ordered = bvh.primitive_indices.iter().map(|&i| triangles[i as usize]).collect();
        Ok(BvhScene { bvh: Some(bvh), triangles: ordered, mesh_count: meshes.len() })
    }

    /// Number of meshes the scene was built from.
    pub fn mesh_count(&self) -> usize {
        self.mesh_count
    }

    /// Bytes held by the acceleration structure: nodes, leaf index list and leaf triangles.
    pub fn memory_bytes(&self) -> usize {
        let bvh = self.bvh.as_ref().map_or(0, |b| {
            b.nodes.len() * std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>()
                + b.primitive_indices.len() * std::mem::size_of::<u32>()
        });
        bvh + self.triangles.len() * std::mem::size_of::<LeafTriangle>()
    }

    /// Closest hit of `ray` in `(tmin, tmax)`. The crate's box test never reports boxes closer than
    /// t = 1.2e-7 (f32 epsilon), so hits nearer than that to the origin are missed; spawned rays
    /// start further off the surface than that.
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let (query, tmin, tmax) = prepare(ray)?;
        let obvhs_ray = to_obvhs_ray(ray, tmin, tmax);
        let mut best: Option<Hit> = None;
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(obvhs_ray, &mut hit, |r, leaf| {
            let tri = &self.triangles[leaf];
            match query.intersect(tri, tmin, r.tmax) {
                Some((t, u, v)) => {
                    best = Some(Hit { t, geom_id: tri.geom_id, prim_id: tri.prim_id, u, v });
                    t
                }
                None => f32::INFINITY,
            }
        });
        best
    }

    /// True if anything lies on `ray` in `(tmin, tmax)`.
    pub fn occluded(&self, ray: &Ray) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        let Some((query, tmin, tmax)) = prepare(ray) else {
            return false;
        };
        let obvhs_ray = to_obvhs_ray(ray, tmin, tmax);
        !bvh.ray_traverse_miss(obvhs_ray, |_, leaf| {
            query.intersect(&self.triangles[leaf], tmin, tmax).map_or(f32::INFINITY, |(t, _, _)| t)
        })
    }
}

impl RayQuery for BvhScene {
    fn name(&self) -> &'static str {
        "bvh"
    }
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        BvhScene::intersect(self, ray)
    }
    fn occluded(&self, ray: &Ray) -> bool {
        BvhScene::occluded(self, ray)
    }
}

fn to_obvhs_ray(ray: &Ray, tmin: f32, tmax: f32) -> obvhs::ray::Ray {
    // obvhs picks a node's near/far planes from `dir < 0` but inverts -0.0 to a negative number, so an
    // axis-parallel ray with a -0.0 component would miss every box; adding +0.0 turns -0.0 into +0.0.
    let dir = ray.dir + Vec3::ZERO;
    // obvhs uses its own glam version; arrays bridge the two.
    obvhs::ray::Ray::new(ray.origin.to_array().into(), dir.to_array().into(), tmin, tmax)
}

/// Rejects rays that cannot hit anything (non-finite, zero direction, NaN or empty interval), the
/// same set the Embree wrapper rejects, and sets up the per-ray part of the watertight test.
fn prepare(ray: &Ray) -> Option<(WatertightRay, f32, f32)> {
    let (tmin, tmax) = super::query_interval(ray)?;
    Some((WatertightRay::new(ray.origin, ray.dir), tmin, tmax))
}

/// Per-ray constants of the watertight test: the axis permutation that makes the dominant direction
/// component z, and the shear that maps the ray onto the +z axis (Woop et al. 2013, §3).
#[derive(Clone, Copy, Debug)]
struct WatertightRay {
    origin: Vec3,
    kx: usize,
    ky: usize,
    kz: usize,
    shear_x: f32,
    shear_y: f32,
    shear_z: f32,
}

impl WatertightRay {
    fn new(origin: Vec3, dir: Vec3) -> WatertightRay {
        let a = dir.abs();
        let kz = if a.x > a.y && a.x > a.z {
            0
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Keep the winding so the sign of the edge functions is orientation-independent.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        WatertightRay {
            origin,
            kx,
            ky,
            kz,
            shear_x: dir[kx] / dir[kz],
            shear_y: dir[ky] / dir[kz],
            shear_z: 1.0 / dir[kz],
        }
    }

    /// (t, u, v) with `tmin < t < tmax`, or None. Edges shared by two triangles are hit by exactly
    /// one or both, never neither: the edge functions are evaluated identically for both triangles
    /// and re-evaluated in f64 when a rounding to exactly zero makes the sign ambiguous.
    fn intersect(&self, tri: &LeafTriangle, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        let a = tri.p0 - self.origin;
        let b = tri.p1 - self.origin;
        let c = tri.p2 - self.origin;
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        let ax = a[kx] - self.shear_x * a[kz];
        let ay = a[ky] - self.shear_y * a[kz];
        let bx = b[kx] - self.shear_x * b[kz];
        let by = b[ky] - self.shear_y * b[kz];
        let cx = c[kx] - self.shear_x * c[kz];
        let cy = c[ky] - self.shear_y * c[kz];
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v == 0.0 || w == 0.0 {
            u = (f64::from(cx) * f64::from(by) - f64::from(cy) * f64::from(bx)) as f32;
            v = (f64::from(ax) * f64::from(cy) - f64::from(ay) * f64::from(cx)) as f32;
            w = (f64::from(bx) * f64::from(ay) - f64::from(by) * f64::from(ax)) as f32;
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let az = self.shear_z * a[kz];
        let bz = self.shear_z * b[kz];
        let cz = self.shear_z * c[kz];
        let t_scaled = u * az + v * bz + w * cz;
        // Compare t against the interval before dividing, with the sign of det folded in.
        let (t_abs, det_abs) = if det < 0.0 { (-t_scaled, -det) } else { (t_scaled, det) };
        if !(t_abs > tmin * det_abs) || !(t_abs < tmax * det_abs) {
            return None;
        }
        let inv_det = 1.0 / det;
        let t = t_scaled * inv_det;
        if !(t > tmin && t < tmax) {
            return None;
        }
        Some((t, v * inv_det, w * inv_det))
    }
}

/// Rejects meshes the backend cannot take (see `TriangleMesh::validate`), naming the element.
fn validate_mesh(index: usize, mesh: &TriangleMesh) -> anyhow::Result<()> {
    mesh.validate(index).map_err(|e| anyhow::anyhow!("BVH: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3]) -> LeafTriangle {
        LeafTriangle { p0: p0.into(), p1: p1.into(), p2: p2.into(), geom_id: 0, prim_id: 0 }
    }

    #[test]
    fn watertight_test_returns_distance_and_barycentrics_in_our_convention() {
        let t = tri([0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]);
        let q = WatertightRay::new(Vec3::new(0.25, 0.5, 0.0), Vec3::Z);
        let (d, u, v) = q.intersect(&t, 0.0, f32::INFINITY).unwrap();
        assert!((d - 2.0).abs() < 1e-6 && (u - 0.25).abs() < 1e-6 && (v - 0.5).abs() < 1e-6, "{d} {u} {v}");
        // Reversed winding and reversed direction hit the same point.
        let back = tri([0.0, 0.0, 2.0], [0.0, 1.0, 2.0], [1.0, 0.0, 2.0]);
        let q2 = WatertightRay::new(Vec3::new(0.25, 0.5, 4.0), -Vec3::Z);
        let (d2, u2, v2) = q2.intersect(&back, 0.0, f32::INFINITY).unwrap();
        assert!((d2 - 2.0).abs() < 1e-6 && (u2 - 0.5).abs() < 1e-6 && (v2 - 0.25).abs() < 1e-6);
        // The interval is open at both ends.
        assert!(q.intersect(&t, 0.0, 2.0).is_none());
        assert!(q.intersect(&t, 2.0, 5.0).is_none());
        assert!(q.intersect(&t, 0.0, 2.0001).is_some());
    }

    #[test]
    fn bad_rays_miss_and_nan_vertices_fail_the_build() {
        let mut m = TriangleMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            indices: vec![[0, 1, 2]],
            ..Default::default()
        };
        let scene = BvhScene::build(std::slice::from_ref(&m)).unwrap();
        let good = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z);
        assert!(scene.intersect(&good).is_some());
        for bad in [
            Ray::new(Vec3::new(f32::NAN, 0.2, -1.0), Vec3::Z),
            Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::new(0.0, f32::INFINITY, 1.0)),
            Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::ZERO),
            Ray { tmin: f32::NAN, ..good },
            Ray { tmax: 0.5, ..good },
        ] {
            assert!(scene.intersect(&bad).is_none() && !scene.occluded(&bad), "{bad:?}");
        }
        m.positions[1].y = f32::NAN;
        let err = BvhScene::build(&[m]).err().unwrap().to_string();
        assert!(err.contains("vertex 1") && err.contains("non-finite"), "{err}");
    }
}
