//! Safe wrapper around Embree 3 (Wald et al., "Embree: A Kernel Framework for Efficient CPU Ray
//! Tracing", SIGGRAPH 2014): one high-quality BVH over world-space triangle meshes, queried with
//! single rays (`rtcIntersect1`) or SIMD packets (`rtcIntersect4/8/16`) chosen per CPU. By default
//! the scene has Mitsuba 3's flags (none: Embree's fast triangle test), so that coincident faces are
//! resolved by the same rounding as in Mitsuba (docs/rough-glass.md); `build_robust` selects Embree's
//! watertight mode instead.
//!
//! `device` owns the Embree device and builds the scene, `rays` holds the single-ray queries and the
//! conversion of our rays to Embree's, `packet` the batched (SIMD packet and stream) queries.

mod device;
mod ffi;
mod packet;
mod rays;

pub use device::{embree_version, flush_denormals_enabled, set_flush_denormals};
pub use packet::PacketHint;

use std::borrow::Borrow;

use anyhow::{bail, Context as _};

use super::{Hit, RayQuery};
use crate::geometry::{Ray, TriangleMesh};
use device::{attach_mesh, choose_packet_width, validate_mesh, Device, SceneHandle};

/// A committed Embree scene over a fixed list of meshes. `Hit::geom_id` is the index of the mesh in the
/// slice given to [`EmbreeScene::build`]; meshes without triangles keep their index but attach nothing.
pub struct EmbreeScene {
    // Field order is drop order: the scene must go before the device it was created on.
    scene: SceneHandle,
    device: Device,
    packet_width: usize,
    mesh_count: usize,
    robust: bool,
}

// SAFETY: Embree documents a committed scene as safe to query from any number of threads at once
// (rtcIntersect*/rtcOccluded* only read the BVH; per-query state lives in the caller's ray and
// context). After `build` returns nothing mutates the scene or the device; the only shared mutable
// state is the error sink, which is an atomic flag plus a mutex.
unsafe impl Send for EmbreeScene {}
// SAFETY: see `Send` above; every `&self` method is a read-only query or reads the error sink.
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds the BVH for `meshes` (world space). Fails with a message naming the mesh and element on
    /// non-finite vertices or out-of-range indices, and with Embree's own message on device errors.
    /// Takes owned meshes, references or `Arc`s alike, so callers need not copy their meshes.
    pub fn build<M: Borrow<TriangleMesh>>(meshes: &[M]) -> anyhow::Result<EmbreeScene> {
        Self::build_with_flags(meshes, ffi::RTC_SCENE_FLAG_NONE)
    }

    /// As [`Self::build`], in Embree's robust mode: a ray aimed exactly at an edge or vertex shared
    /// by two triangles hits one of them (the default test lets about one such ray in a thousand slip
    /// through), at some cost in speed.
    pub fn build_robust<M: Borrow<TriangleMesh>>(meshes: &[M]) -> anyhow::Result<EmbreeScene> {
        Self::build_with_flags(meshes, ffi::RTC_SCENE_FLAG_ROBUST)
    }

    fn build_with_flags<M: Borrow<TriangleMesh>>(
        meshes: &[M],
        flags: ffi::RTCSceneFlags,
    ) -> anyhow::Result<EmbreeScene> {
        if meshes.len() >= ffi::RTC_INVALID_GEOMETRY_ID as usize {
            bail!("Embree: {} meshes exceed the geometry id range", meshes.len());
        }
        for (index, mesh) in meshes.iter().enumerate() {
            validate_mesh(index, mesh.borrow())?;
        }

        let device = Device::new()?;
        // SAFETY: `device.raw` is a live device; a null return is handled right below.
        let raw_scene = unsafe { ffi::rtcNewScene(device.raw) };
        device.check("creating the scene")?;
        if raw_scene.is_null() {
            bail!("Embree: rtcNewScene returned no scene");
        }
        let scene = SceneHandle(raw_scene);
        // SAFETY: `scene.0` is a live, uncommitted scene owned by this function.
        unsafe {
            ffi::rtcSetSceneFlags(scene.0, flags);
            ffi::rtcSetSceneBuildQuality(scene.0, ffi::RTC_BUILD_QUALITY_HIGH);
        }
        device.check("setting scene flags")?;

        for (index, mesh) in meshes.iter().enumerate() {
            let mesh = mesh.borrow();
            if mesh.indices.is_empty() {
                continue;
            }
            attach_mesh(&device, &scene, index, mesh)
                .with_context(|| format!("Embree: building {}", mesh.label(index)))?;
        }

        // SAFETY: all geometries are committed and attached; the scene is committed once.
        unsafe { ffi::rtcCommitScene(scene.0) };
        device.check("committing the scene (BVH build)")?;

        let packet_width = choose_packet_width(&device);
        Ok(EmbreeScene {
            scene,
            device,
            packet_width,
            mesh_count: meshes.len(),
            robust: flags == ffi::RTC_SCENE_FLAG_ROBUST,
        })
    }

    /// Rays per `rtcIntersectN` call used by the batch methods: 16, 8 or 4 by CPU and library
    /// support, or 1 if this Embree build has no packet kernels.
    pub fn packet_width(&self) -> usize {
        self.packet_width
    }

    /// Number of meshes the scene was built from (the valid range of `Hit::geom_id`, empty meshes included).
    pub fn mesh_count(&self) -> usize {
        self.mesh_count
    }

    /// Returns (and clears) any error Embree reported since the last check.
    pub fn check_error(&self) -> anyhow::Result<()> {
        self.device.check("a ray query")
    }

    /// Errors during queries mean this wrapper handed Embree something it should not have (every
    /// ray is validated first), so debug builds stop right there instead of returning wrong hits.
    #[inline]
    fn debug_check(&self) {
        #[cfg(debug_assertions)]
        if self.device.has_errors() {
            if let Err(e) = self.check_error() {
                panic!("Embree reported an error during a query: {e:#}");
            }
        }
    }
}

impl RayQuery for EmbreeScene {
    fn name(&self) -> &'static str {
        if self.robust {
            "embree-robust"
        } else {
            "embree"
        }
    }
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        EmbreeScene::intersect(self, ray)
    }
    fn occluded(&self, ray: &Ray) -> bool {
        EmbreeScene::occluded(self, ray)
    }
    fn intersect_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        EmbreeScene::intersect_batch(self, rays, hits)
    }
    fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) {
        EmbreeScene::occluded_batch(self, rays, occluded)
    }
}
