//! Safe wrapper around Embree 3 (Wald et al., "Embree: A Kernel Framework for Efficient CPU Ray
//! Tracing", SIGGRAPH 2014): one high-quality BVH over world-space triangle meshes, queried with
//! single rays (`rtcIntersect1`) or SIMD packets (`rtcIntersect4/8/16`) chosen per CPU. By default
//! the scene has Mitsuba 3's flags (none: Embree's fast triangle test), so that coincident faces are
//! resolved by the same rounding as in Mitsuba (docs/rough-glass.md); `build_robust` selects Embree's
//! watertight mode instead.

mod ffi;

use std::borrow::Borrow;
use std::ffi::{c_char, c_int, c_void, CStr};
use std::ptr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use anyhow::{anyhow, bail, Context as _};

use super::{Hit, RayQuery};
use crate::geometry::{Ray, TriangleMesh, Vec3};

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

    /// Closest hit of `ray` in `(tmin, tmax)` (see [`RayQuery::intersect`]).
    // The per-ray path is kept to what `rtcIntersect1` needs: one combined validity test, the ray
    // written straight into Embree's struct, a context built from constants (three stores), and the
    // hit read back; `#[inline]` lets callers in other modules fold it into their loops.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let mut rayhit = ffi::RTCRayHit { ray: rtc_ray(ray)?, hit: no_hit() };
        let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
        // SAFETY: the scene is committed; `rayhit` and `context` are valid, properly aligned
        // (RTCRayHit is align(16) by its bindgen repr) and live for the call. The ray was checked finite.
        unsafe { ffi::rtcIntersect1(self.scene.0, &mut context, &mut rayhit) };
        self.debug_check();
        hit_of(&rayhit)
    }

    /// True if anything lies on `ray` in `(tmin, tmax)`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        let Some(mut rtc) = rtc_ray(ray) else {
            return false;
        };
        let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
        // SAFETY: as in `intersect`; rtcOccluded1 only writes `rtc.tfar`.
        unsafe { ffi::rtcOccluded1(self.scene.0, &mut context, &mut rtc) };
        self.debug_check();
        // Embree marks an occluded ray by setting tfar to -inf.
        rtc.tfar == f32::NEG_INFINITY
    }

    /// Closest hits for `rays` (`hits.len()` should equal `rays.len()`; the shorter length is
    /// processed, as with the trait's default methods), by the strategy
    /// `hslt bench rays` measured fastest on every ray set (docs/benchmarks.md): packets of
    /// [`Self::packet_width`] rays, with Embree's coherent (frustum) traversal for packets whose rays
    /// share one origin — camera rays, manifold-corrector bundles — and its hybrid packet/single-ray
    /// traversal otherwise.
    pub fn intersect_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        // A packet with one live lane costs more than the single-ray kernel (the corrector's rows
        // often hold one ray).
        if let ([ray], [hit]) = (rays, &mut *hits) {
            *hit = self.intersect(ray);
            return;
        }
        self.intersect_packets(rays, hits, PacketHint::SharedOrigin);
    }

    /// Occlusion for `rays` (`occluded.len()` should equal `rays.len()`); same strategy as
    /// [`Self::intersect_batch`].
    pub fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) {
        if let ([ray], [blocked]) = (rays, &mut *occluded) {
            *blocked = self.occluded(ray);
            return;
        }
        self.occluded_packets(rays, occluded, PacketHint::SharedOrigin);
    }

    /// Closest hits in packets of [`Self::packet_width`] with the given coherence hint (single
    /// rays with one shared context when this Embree has no packet kernels).
    pub fn intersect_packets(&self, rays: &[Ray], hits: &mut [Option<Hit>], hint: PacketHint) {
        debug_assert_eq!(rays.len(), hits.len(), "intersect_packets: length mismatch");
        match self.packet_width {
            16 => self.intersect_packets16(rays, hits, hint),
            8 => self.intersect_packets8(rays, hits, hint),
            4 => self.intersect_packets4(rays, hits, hint),
            _ => {
                let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
                for (ray, hit) in rays.iter().zip(hits.iter_mut()) {
                    *hit = rtc_ray(ray).and_then(|ray| {
                        let mut rayhit = ffi::RTCRayHit { ray, hit: no_hit() };
                        // SAFETY: as in `intersect`; the context is reused, which Embree allows.
                        unsafe { ffi::rtcIntersect1(self.scene.0, &mut context, &mut rayhit) };
                        hit_of(&rayhit)
                    });
                }
            }
        }
        self.debug_check();
    }

    /// Occlusion in packets of [`Self::packet_width`] with the given coherence hint.
    pub fn occluded_packets(&self, rays: &[Ray], occluded: &mut [bool], hint: PacketHint) {
        debug_assert_eq!(rays.len(), occluded.len(), "occluded_packets: length mismatch");
        match self.packet_width {
            16 => self.occluded_packets16(rays, occluded, hint),
            8 => self.occluded_packets8(rays, occluded, hint),
            4 => self.occluded_packets4(rays, occluded, hint),
            _ => {
                let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
                for (ray, o) in rays.iter().zip(occluded.iter_mut()) {
                    *o = rtc_ray(ray).is_some_and(|mut rtc| {
                        // SAFETY: as in `occluded`; the context is reused, which Embree allows.
                        unsafe { ffi::rtcOccluded1(self.scene.0, &mut context, &mut rtc) };
                        rtc.tfar == f32::NEG_INFINITY
                    });
                }
            }
        }
        self.debug_check();
    }

    /// Errors during queries mean this wrapper handed Embree something it should not have (every
    /// ray is validated first), so debug builds stop right there instead of returning wrong hits.
    #[inline]
    fn debug_check(&self) {
        #[cfg(debug_assertions)]
        if self.device.errors.any.load(Ordering::Relaxed) {
            if let Err(e) = self.check_error() {
                panic!("Embree reported an error during a query: {e:#}");
            }
        }
    }
}

/// Stream queries (`rtcIntersect1M`/`rtcOccluded1M`) and a raw-bindings loop, for `hslt bench rays`.
impl EmbreeScene {
    /// Closest hits through Embree's stream API: the rays go in one array and Embree regroups them
    /// into packets itself. `coherent` sets the context hint. Invalid rays get `None`.
    pub fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>], coherent: bool) {
        debug_assert_eq!(rays.len(), hits.len(), "intersect_stream: length mismatch");
        let mut stream: Vec<ffi::RTCRayHit> = Vec::with_capacity(rays.len());
        let mut valid = Vec::with_capacity(rays.len());
        for ray in rays {
            let rtc = rtc_ray(ray);
            valid.push(rtc.is_some());
            // An invalid ray becomes an empty interval, which Embree skips.
            stream.push(ffi::RTCRayHit { ray: rtc.unwrap_or(EMPTY_RAY), hit: no_hit() });
        }
        let mut context = new_context(coherence_flag(coherent));
        // SAFETY: the scene is committed; `stream` holds `rays.len()` initialised, aligned RTCRayHit
        // structs laid out with their own size as stride, and lives for the call.
        unsafe {
            ffi::rtcIntersect1M(
                self.scene.0,
                &mut context,
                stream.as_mut_ptr(),
                stream.len() as u32,
                std::mem::size_of::<ffi::RTCRayHit>(),
            )
        };
        self.debug_check();
        for ((rh, ok), hit) in stream.iter().zip(valid).zip(hits.iter_mut()) {
            *hit = if ok { hit_of(rh) } else { None };
        }
    }

    /// Occlusion through `rtcOccluded1M` (see [`Self::intersect_stream`]).
    pub fn occluded_stream(&self, rays: &[Ray], occluded: &mut [bool], coherent: bool) {
        debug_assert_eq!(rays.len(), occluded.len(), "occluded_stream: length mismatch");
        let mut stream: Vec<ffi::RTCRay> = rays.iter().map(|ray| rtc_ray(ray).unwrap_or(EMPTY_RAY)).collect();
        let mut context = new_context(coherence_flag(coherent));
        // SAFETY: as in `intersect_stream`, with RTCRay elements.
        unsafe {
            ffi::rtcOccluded1M(
                self.scene.0,
                &mut context,
                stream.as_mut_ptr(),
                stream.len() as u32,
                std::mem::size_of::<ffi::RTCRay>(),
            )
        };
        self.debug_check();
        for (r, o) in stream.iter().zip(occluded.iter_mut()) {
            *o = r.tfar == f32::NEG_INFINITY;
        }
    }

    /// The baseline for the wrapper's overhead: `rtcIntersect1` on each ray straight from the
    /// bindings, with no validation or conversion to `Hit`. Returns the number of hits. The rays
    /// must be finite with `0 <= tmin < tmax` (unchecked input only yields misses, never UB).
    // Never inlined, so callgrind can count its instructions on their own (`--toggle-collect`).
    #[inline(never)]
    pub fn raw_intersect1_loop(&self, rays: &[Ray]) -> usize {
        let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
        let mut hits = 0;
        for ray in rays {
            let mut rayhit = ffi::RTCRayHit {
                ray: ffi::RTCRay {
                    org_x: ray.origin.x,
                    org_y: ray.origin.y,
                    org_z: ray.origin.z,
                    tnear: ray.tmin,
                    dir_x: ray.dir.x,
                    dir_y: ray.dir.y,
                    dir_z: ray.dir.z,
                    time: 0.0,
                    tfar: ray.tmax,
                    mask: u32::MAX,
                    id: 0,
                    flags: 0,
                },
                hit: ffi::RTCHit { geomID: ffi::RTC_INVALID_GEOMETRY_ID, ..Default::default() },
            };
            // SAFETY: as in `intersect`; the struct is valid and aligned. Embree treats non-finite
            // input as a miss or reports an error through the callback, it does not read out of bounds.
            unsafe { ffi::rtcIntersect1(self.scene.0, &mut context, &mut rayhit) };
            hits += usize::from(rayhit.hit.geomID != ffi::RTC_INVALID_GEOMETRY_ID);
        }
        hits
    }
}

/// One packet kernel per SIMD width; the RTCRayHitN/RTCRayN structs differ only in lane count. The
/// packet struct and the context live across the whole batch; only the lanes and the valid mask are
/// rewritten per packet (stale data in masked-off lanes is never read by Embree).
macro_rules! packet_kernels {
    ($lanes:literal, $intersect:ident, $occluded:ident, $RayHitN:ty, $RayN:ty,
     $rtc_intersect:path, $rtc_occluded:path) => {
        impl EmbreeScene {
            fn $intersect(&self, rays: &[Ray], hits: &mut [Option<Hit>], hint: PacketHint) {
                let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
                let mut packet = <$RayHitN>::default();
                for (ray_chunk, hit_chunk) in rays.chunks($lanes).zip(hits.chunks_mut($lanes)) {
                    let mut valid = ValidMask::default();
                    let mut origin = SharedOrigin::default();
                    for (lane, ray) in ray_chunk.iter().enumerate() {
                        packet.hit.geomID[lane] = ffi::RTC_INVALID_GEOMETRY_ID;
                        if let Some(r) = rtc_ray(ray) {
                            valid.0[lane] = -1;
                            origin.add(ray.origin);
                            set_lane!(packet.ray, lane, r);
                        }
                    }
                    if origin.is_empty() {
                        hit_chunk.fill(None);
                        continue;
                    }
                    context.flags = hint.flags(&origin);
                    // SAFETY: the scene is committed; `valid` is 64-byte aligned with at least
                    // $lanes entries, `packet` is aligned by its bindgen repr, inactive lanes are
                    // masked off, and every active lane holds a finite ray.
                    unsafe { $rtc_intersect(valid.0.as_ptr(), self.scene.0, &mut context, &mut packet) };
                    for (lane, hit) in hit_chunk.iter_mut().enumerate() {
                        let geom_id = packet.hit.geomID[lane];
                        *hit = (valid.0[lane] != 0 && geom_id != ffi::RTC_INVALID_GEOMETRY_ID).then(|| Hit {
                            t: packet.ray.tfar[lane],
                            geom_id,
                            prim_id: packet.hit.primID[lane],
                            u: packet.hit.u[lane],
                            v: packet.hit.v[lane],
                        });
                    }
                }
            }

            fn $occluded(&self, rays: &[Ray], occluded: &mut [bool], hint: PacketHint) {
                let mut context = new_context(ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
                let mut packet = <$RayN>::default();
                for (ray_chunk, out_chunk) in rays.chunks($lanes).zip(occluded.chunks_mut($lanes)) {
                    let mut valid = ValidMask::default();
                    let mut origin = SharedOrigin::default();
                    for (lane, ray) in ray_chunk.iter().enumerate() {
                        if let Some(r) = rtc_ray(ray) {
                            valid.0[lane] = -1;
                            origin.add(ray.origin);
                            set_lane!(packet, lane, r);
                        }
                    }
                    if origin.is_empty() {
                        out_chunk.fill(false);
                        continue;
                    }
                    context.flags = hint.flags(&origin);
                    // SAFETY: as for the intersect kernel of the same width.
                    unsafe { $rtc_occluded(valid.0.as_ptr(), self.scene.0, &mut context, &mut packet) };
                    for (lane, out) in out_chunk.iter_mut().enumerate() {
                        *out = valid.0[lane] != 0 && packet.tfar[lane] == f32::NEG_INFINITY;
                    }
                }
            }
        }
    };
}

macro_rules! set_lane {
    ($ray:expr, $lane:expr, $r:expr) => {{
        let (lane, r) = ($lane, &$r);
        $ray.org_x[lane] = r.org_x;
        $ray.org_y[lane] = r.org_y;
        $ray.org_z[lane] = r.org_z;
        $ray.dir_x[lane] = r.dir_x;
        $ray.dir_y[lane] = r.dir_y;
        $ray.dir_z[lane] = r.dir_z;
        $ray.tnear[lane] = r.tnear;
        $ray.tfar[lane] = r.tfar;
        $ray.time[lane] = r.time;
        $ray.mask[lane] = r.mask;
        $ray.id[lane] = r.id;
        $ray.flags[lane] = r.flags;
    }};
}

packet_kernels!(
    16,
    intersect_packets16,
    occluded_packets16,
    ffi::RTCRayHit16,
    ffi::RTCRay16,
    ffi::rtcIntersect16,
    ffi::rtcOccluded16
);
packet_kernels!(
    8,
    intersect_packets8,
    occluded_packets8,
    ffi::RTCRayHit8,
    ffi::RTCRay8,
    ffi::rtcIntersect8,
    ffi::rtcOccluded8
);
packet_kernels!(
    4,
    intersect_packets4,
    occluded_packets4,
    ffi::RTCRayHit4,
    ffi::RTCRay4,
    ffi::rtcIntersect4,
    ffi::rtcOccluded4
);

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

/// The coherence hint the packet kernels give Embree. With the incoherent hint Embree's 8-wide packet
/// traversal falls back to single rays as soon as 7 or fewer lanes are active at a node (for 8-wide
/// BVHs), so a packet costs about as much as its rays one by one; the coherent hint selects the
/// frustum traversal, which tests each node once against the whole packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PacketHint {
    /// Always `RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT`.
    Incoherent,
    /// Always `RTC_INTERSECT_CONTEXT_FLAG_COHERENT`.
    Coherent,
    /// Coherent for packets whose valid rays share one origin (pinhole camera rays, corrector
    /// bundles from one vertex), incoherent otherwise.
    SharedOrigin,
}

impl PacketHint {
    #[inline]
    fn flags(self, origin: &SharedOrigin) -> ffi::RTCIntersectContextFlags {
        let coherent = match self {
            PacketHint::Incoherent => false,
            PacketHint::Coherent => true,
            PacketHint::SharedOrigin => origin.shared,
        };
        coherence_flag(coherent)
    }
}

/// Tracks whether the valid rays of one packet so far all start at the same point.
#[derive(Default)]
struct SharedOrigin {
    first: Option<Vec3>,
    shared: bool,
}

impl SharedOrigin {
    #[inline]
    fn add(&mut self, origin: Vec3) {
        match self.first {
            None => {
                self.first = Some(origin);
                self.shared = true;
            }
            Some(first) => self.shared &= first == origin,
        }
    }

    fn is_empty(&self) -> bool {
        self.first.is_none()
    }
}

/// Packet valid mask: Embree reads it with aligned SIMD loads (16/32/64 bytes for 4/8/16 lanes), so
/// one 64-byte aligned, 16-lane mask serves every width.
#[repr(C, align(64))]
#[derive(Default)]
struct ValidMask([c_int; 16]);

/// `ray` as Embree's struct, or `None` when it cannot hit anything or would be invalid input for
/// Embree (see [`super::query_interval`]).
// Embree accepts tnear < t <= tfar, and its t carries a few ulps of error (it multiplies by an
// approximate reciprocal: a hit at exactly t = 1 comes back as 1 - 2^-24), so the ends of the interval
// only hold up to that precision. Shadow rays must shrink their segment by a relative epsilon anyway;
// shifting tfar by an ulp here would promise more than Embree keeps.
#[inline]
fn rtc_ray(ray: &Ray) -> Option<ffi::RTCRay> {
    let (tnear, tfar) = super::query_interval(ray)?;
    Some(ffi::RTCRay {
        org_x: ray.origin.x,
        org_y: ray.origin.y,
        org_z: ray.origin.z,
        tnear,
        dir_x: ray.dir.x,
        dir_y: ray.dir.y,
        dir_z: ray.dir.z,
        time: 0.0,
        tfar,
        mask: u32::MAX,
        id: 0,
        flags: 0,
    })
}

/// Stands in for invalid rays in streams: an empty interval, which Embree skips.
const EMPTY_RAY: ffi::RTCRay = ffi::RTCRay {
    org_x: 0.0,
    org_y: 0.0,
    org_z: 0.0,
    tnear: 1.0,
    dir_x: 0.0,
    dir_y: 0.0,
    dir_z: 1.0,
    time: 0.0,
    tfar: 0.0,
    mask: u32::MAX,
    id: 0,
    flags: 0,
};

/// The hit record before a query: Embree writes it only on a hit, and `geomID` tells which.
#[inline]
fn no_hit() -> ffi::RTCHit {
    ffi::RTCHit {
        geomID: ffi::RTC_INVALID_GEOMETRY_ID,
        primID: ffi::RTC_INVALID_GEOMETRY_ID,
        instID: [ffi::RTC_INVALID_GEOMETRY_ID; ffi::RTC_MAX_INSTANCE_LEVEL_COUNT as usize],
        ..Default::default()
    }
}

#[inline]
fn hit_of(rayhit: &ffi::RTCRayHit) -> Option<Hit> {
    (rayhit.hit.geomID != ffi::RTC_INVALID_GEOMETRY_ID).then_some(Hit {
        t: rayhit.ray.tfar,
        geom_id: rayhit.hit.geomID,
        prim_id: rayhit.hit.primID,
        u: rayhit.hit.u,
        v: rayhit.hit.v,
    })
}

fn coherence_flag(coherent: bool) -> ffi::RTCIntersectContextFlags {
    if coherent {
        ffi::RTC_INTERSECT_CONTEXT_FLAG_COHERENT
    } else {
        ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT
    }
}

/// An intersect context with the given hint and no filter or instance stack: what
/// `rtcInitIntersectContext` builds, written inline so it costs a few stores per query.
#[inline]
fn new_context(flags: ffi::RTCIntersectContextFlags) -> ffi::RTCIntersectContext {
    #[allow(clippy::needless_update)]
    ffi::RTCIntersectContext {
        flags,
        filter: None,
        instID: [ffi::RTC_INVALID_GEOMETRY_ID; ffi::RTC_MAX_INSTANCE_LEVEL_COUNT as usize],
        ..Default::default()
    }
}

/// Embree silently drops triangles with NaN vertices and reads out of bounds on bad indices, so such
/// meshes are rejected here (see `TriangleMesh::validate`) with the offending element named.
fn validate_mesh(index: usize, mesh: &TriangleMesh) -> anyhow::Result<()> {
    mesh.validate(index).map_err(|e| anyhow::anyhow!("Embree: {e}"))
}

fn attach_mesh(
    device: &Device,
    scene: &SceneHandle,
    index: usize,
    mesh: &TriangleMesh,
) -> anyhow::Result<()> {
    // SAFETY: `device.raw` is live; a null result is handled below.
    let raw = unsafe { ffi::rtcNewGeometry(device.raw, ffi::RTC_GEOMETRY_TYPE_TRIANGLE) };
    device.check("creating a triangle geometry")?;
    if raw.is_null() {
        bail!("rtcNewGeometry returned no geometry");
    }
    let geometry = GeometryHandle(raw);

    // SAFETY: Embree allocates the buffers (with the tail padding its SIMD loads need) and returns
    // pointers to `count * stride` bytes, or null on error, which is checked before writing.
    let (vertex_ptr, index_ptr) = unsafe {
        let vertex_ptr = ffi::rtcSetNewGeometryBuffer(
            geometry.0,
            ffi::RTC_BUFFER_TYPE_VERTEX,
            0,
            ffi::RTC_FORMAT_FLOAT3,
            3 * std::mem::size_of::<f32>(),
            mesh.positions.len(),
        );
        let index_ptr = ffi::rtcSetNewGeometryBuffer(
            geometry.0,
            ffi::RTC_BUFFER_TYPE_INDEX,
            0,
            ffi::RTC_FORMAT_UINT3,
            3 * std::mem::size_of::<u32>(),
            mesh.indices.len(),
        );
        (vertex_ptr, index_ptr)
    };
    device.check("allocating vertex and index buffers")?;
    if vertex_ptr.is_null() || index_ptr.is_null() {
        bail!("rtcSetNewGeometryBuffer returned no buffer");
    }
    // SAFETY: each buffer holds exactly as many tightly packed float3/uint3 items as we copy; Embree
    // aligns buffers to at least 16 bytes, so the f32/u32 writes are aligned; the regions are fresh
    // allocations that cannot overlap our slices.
    unsafe {
        let vertices = std::slice::from_raw_parts_mut(vertex_ptr.cast::<f32>(), 3 * mesh.positions.len());
        for (dst, p) in vertices.chunks_exact_mut(3).zip(&mesh.positions) {
            dst.copy_from_slice(&p.to_array());
        }
        let indices = std::slice::from_raw_parts_mut(index_ptr.cast::<u32>(), 3 * mesh.indices.len());
        for (dst, tri) in indices.chunks_exact_mut(3).zip(&mesh.indices) {
            dst.copy_from_slice(tri);
        }
    }

    // SAFETY: the geometry is complete; attaching by id keeps `geom_id == index` even when empty
    // meshes in between were skipped. `index` < RTC_INVALID_GEOMETRY_ID was checked in `build`.
    unsafe {
        ffi::rtcSetGeometryBuildQuality(geometry.0, ffi::RTC_BUILD_QUALITY_HIGH);
        ffi::rtcCommitGeometry(geometry.0);
        ffi::rtcAttachGeometryByID(scene.0, geometry.0, index as u32);
    }
    device.check("committing and attaching the geometry")?;
    Ok(())
}

/// Collects messages from Embree's error callback, which may run on any thread.
#[derive(Default)]
struct ErrorSink {
    any: AtomicBool,
    messages: Mutex<Vec<String>>,
}

impl ErrorSink {
    fn push(&self, message: String) {
        self.messages.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).push(message);
        self.any.store(true, Ordering::Release);
    }

    fn take(&self) -> Vec<String> {
        if !self.any.swap(false, Ordering::Acquire) {
            return Vec::new();
        }
        std::mem::take(&mut *self.messages.lock().unwrap_or_else(|poisoned| poisoned.into_inner()))
    }
}

unsafe extern "C" fn on_device_error(user_ptr: *mut c_void, code: ffi::RTCError, message: *const c_char) {
    if user_ptr.is_null() {
        return;
    }
    // SAFETY: `user_ptr` is the `Box<ErrorSink>` registered in `Device::new`, which outlives the device.
    let sink = unsafe { &*user_ptr.cast::<ErrorSink>() };
    let text = if message.is_null() {
        String::new()
    } else {
        // SAFETY: Embree passes a NUL-terminated string valid for the duration of the callback.
        unsafe { CStr::from_ptr(message) }.to_string_lossy().into_owned()
    };
    sink.push(format!("{} ({text})", error_name(code)));
}

fn error_name(code: ffi::RTCError) -> &'static str {
    match code {
        ffi::RTC_ERROR_NONE => "no error",
        ffi::RTC_ERROR_INVALID_ARGUMENT => "invalid argument",
        ffi::RTC_ERROR_INVALID_OPERATION => "invalid operation",
        ffi::RTC_ERROR_OUT_OF_MEMORY => "out of memory",
        ffi::RTC_ERROR_UNSUPPORTED_CPU => "unsupported CPU",
        ffi::RTC_ERROR_CANCELLED => "cancelled",
        ffi::RTC_ERROR_UNKNOWN => "unknown error",
        _ => "unrecognised error code",
    }
}

/// Owns an `RTCDevice` and the sink its error callback writes to.
struct Device {
    raw: ffi::RTCDevice,
    errors: Box<ErrorSink>,
}

impl Device {
    fn new() -> anyhow::Result<Device> {
        // SAFETY: a null config string selects Embree's defaults.
        let raw = unsafe { ffi::rtcNewDevice(ptr::null()) };
        if raw.is_null() {
            // SAFETY: with a null device, rtcGetDeviceError reports the thread's last device-creation error.
            let code = unsafe { ffi::rtcGetDeviceError(ptr::null_mut()) };
            bail!("Embree: rtcNewDevice failed: {}", error_name(code));
        }
        let errors = Box::<ErrorSink>::default();
        // SAFETY: the callback only touches the sink through `user_ptr`; the box is heap-stable and
        // dropped after the device is released (see `Drop`).
        unsafe {
            ffi::rtcSetDeviceErrorFunction(
                raw,
                Some(on_device_error),
                ptr::from_ref::<ErrorSink>(&errors).cast_mut().cast::<c_void>(),
            )
        };
        Ok(Device { raw, errors })
    }

    /// Turns errors reported since the last check into one `anyhow` error.
    fn check(&self, during: &str) -> anyhow::Result<()> {
        // SAFETY: `raw` is live; this reads and clears the calling thread's error code.
        let code = unsafe { ffi::rtcGetDeviceError(self.raw) };
        let messages = self.errors.take();
        if messages.is_empty() && code == ffi::RTC_ERROR_NONE {
            return Ok(());
        }
        let detail = if messages.is_empty() { error_name(code).to_string() } else { messages.join("; ") };
        Err(anyhow!("Embree error while {during}: {detail}"))
    }

    fn property(&self, property: ffi::RTCDeviceProperty) -> isize {
        // SAFETY: `raw` is live; unknown properties yield an error code, not UB.
        unsafe { ffi::rtcGetDeviceProperty(self.raw, property) }
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: we hold the only reference we created; scenes keep their own references.
        unsafe { ffi::rtcReleaseDevice(self.raw) };
    }
}

struct SceneHandle(ffi::RTCScene);

impl Drop for SceneHandle {
    fn drop(&mut self) {
        // SAFETY: releases the reference taken by rtcNewScene exactly once.
        unsafe { ffi::rtcReleaseScene(self.0) };
    }
}

struct GeometryHandle(ffi::RTCGeometry);

impl Drop for GeometryHandle {
    fn drop(&mut self) {
        // SAFETY: releases the reference from rtcNewGeometry; an attached scene keeps its own.
        unsafe { ffi::rtcReleaseGeometry(self.0) };
    }
}

/// Widest packet that both the Embree build (native kernels for that width) and the CPU support;
/// emulated wide packets would only add overhead over narrower native ones.
fn choose_packet_width(device: &Device) -> usize {
    let native = |p| device.property(p) != 0;
    let (has_avx512, has_avx) = cpu_simd();
    if native(ffi::RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) && has_avx512 {
        16
    } else if native(ffi::RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED) && has_avx {
        8
    } else if native(ffi::RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED) {
        4
    } else {
        1
    }
}

#[cfg(target_arch = "x86_64")]
fn cpu_simd() -> (bool, bool) {
    (std::arch::is_x86_feature_detected!("avx512f"), std::arch::is_x86_feature_detected!("avx"))
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_simd() -> (bool, bool) {
    (false, false)
}

/// Version of the Embree library loaded at run time, e.g. "3.13.5" (may differ from the headers at
/// build time by patch level).
pub fn embree_version() -> String {
    match Device::new() {
        Ok(device) => {
            use ffi::*;
            let major = device.property(RTC_DEVICE_PROPERTY_VERSION_MAJOR);
            let minor = device.property(RTC_DEVICE_PROPERTY_VERSION_MINOR);
            let patch = device.property(RTC_DEVICE_PROPERTY_VERSION_PATCH);
            format!("{major}.{minor}.{patch}")
        }
        Err(e) => format!("unavailable ({e})"),
    }
}

const MXCSR_DAZ: u32 = 1 << 6;
const MXCSR_FTZ: u32 = 1 << 15;

/// Sets flush-to-zero and denormals-are-zero in the calling thread's MXCSR, as Embree recommends for
/// every thread that traces rays (denormal arithmetic in BVH traversal is many times slower). Call it
/// at the start of each render worker thread. No-op outside x86_64.
pub fn set_flush_denormals() {
    #[cfg(target_arch = "x86_64")]
    {
        let csr = read_mxcsr() | MXCSR_FTZ | MXCSR_DAZ;
        // SAFETY: ldmxcsr only changes this thread's SSE control flags; FTZ/DAZ alter how denormal
        // results and inputs round (to zero), never memory safety. LLVM assumes the default
        // floating-point environment, so constant-folded and run-time results may differ for
        // denormals; the renderer treats denormal-scale values as zero anyway.
        unsafe {
            std::arch::asm!("ldmxcsr [{}]", in(reg) ptr::from_ref(&csr), options(nostack, readonly, preserves_flags))
        };
    }
}

/// True if the calling thread has both FTZ and DAZ set (always false outside x86_64).
pub fn flush_denormals_enabled() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        read_mxcsr() & (MXCSR_FTZ | MXCSR_DAZ) == (MXCSR_FTZ | MXCSR_DAZ)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
fn read_mxcsr() -> u32 {
    let mut csr = 0u32;
    // SAFETY: stmxcsr stores the 32-bit MXCSR into `csr`, a live, aligned local.
    unsafe {
        std::arch::asm!("stmxcsr [{}]", in(reg) ptr::from_mut(&mut csr), options(nostack, preserves_flags))
    };
    csr
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(origin: [f32; 3], dir: [f32; 3], tmin: f32, tmax: f32) -> Ray {
        Ray { origin: Vec3::from(origin), dir: Vec3::from(dir), tmin, tmax }
    }

    #[test]
    fn rtc_ray_rejects_what_embree_cannot_take() {
        let ok = ray([0.0; 3], [0.0, 0.0, 1.0], 0.0, f32::INFINITY);
        assert!(rtc_ray(&ok).is_some());
        for bad in [
            ray([f32::NAN, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0, 1.0),
            ray([0.0; 3], [0.0, f32::INFINITY, 1.0], 0.0, 1.0),
            ray([0.0; 3], [0.0, 0.0, 0.0], 0.0, 1.0),
            ray([0.0; 3], [0.0, 0.0, 1.0], f32::NAN, 1.0),
            ray([0.0; 3], [0.0, 0.0, 1.0], 0.0, f32::NAN),
            ray([0.0; 3], [0.0, 0.0, 1.0], 2.0, 1.0),
            ray([0.0; 3], [0.0, 0.0, 1.0], 1.0, 1.0),
            ray([0.0; 3], [0.0, 0.0, 1.0], 0.0, 0.0),
            ray([0.0, f32::NEG_INFINITY, 0.0], [0.0, 0.0, 1.0], 0.0, 1.0),
            ray([0.0; 3], [f32::NAN, 0.0, 1.0], 0.0, 1.0),
            ray([0.0; 3], [0.0, 0.0, 1.0], f32::NEG_INFINITY, f32::NEG_INFINITY),
        ] {
            assert!(rtc_ray(&bad).is_none(), "{bad:?} should be rejected");
        }
    }

    #[test]
    fn rtc_ray_clamps_negative_tnear() {
        let p = rtc_ray(&ray([0.0; 3], [1.0, 0.0, 0.0], -3.0, 2.0)).unwrap();
        assert_eq!(p.tnear, 0.0);
        assert_eq!(p.tfar, 2.0);
        let unbounded = rtc_ray(&ray([0.0; 3], [1.0, 0.0, 0.0], 0.5, f32::INFINITY)).unwrap();
        // Huge but finite coordinates are valid input.
        assert!(rtc_ray(&ray([f32::MAX, 0.0, -f32::MAX], [1e-30, 0.0, 0.0], 0.0, 1.0)).is_some());
        assert_eq!(unbounded.tfar, f32::INFINITY);
        assert_eq!(unbounded.tnear, 0.5);
    }

    #[test]
    fn shared_origin_hint_is_coherent_only_for_one_origin() {
        let hint = PacketHint::SharedOrigin;
        let mut origin = SharedOrigin::default();
        assert!(origin.is_empty());
        origin.add(Vec3::new(1.0, 2.0, 3.0));
        origin.add(Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(hint.flags(&origin), ffi::RTC_INTERSECT_CONTEXT_FLAG_COHERENT);
        origin.add(Vec3::new(1.0, 2.0, 3.5));
        origin.add(Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(hint.flags(&origin), ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
        assert_eq!(PacketHint::Coherent.flags(&origin), ffi::RTC_INTERSECT_CONTEXT_FLAG_COHERENT);
        let mut single = SharedOrigin::default();
        single.add(Vec3::ZERO);
        assert_eq!(PacketHint::Incoherent.flags(&single), ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
    }

    #[test]
    fn valid_mask_is_aligned_for_sixteen_lanes() {
        let mask = ValidMask::default();
        assert_eq!(std::mem::align_of::<ValidMask>(), 64);
        assert_eq!((mask.0.as_ptr() as usize) % 64, 0);
        assert!(mask.0.iter().all(|&lane| lane == 0), "a fresh mask must have every lane off");
    }

    #[test]
    fn device_errors_become_anyhow_errors() {
        let device = Device::new().unwrap();
        // Embree rejects an invalid geometry type through the error callback.
        // SAFETY: the device is live; Embree reports the bad type through the callback and returns null.
        let geometry = unsafe { ffi::rtcNewGeometry(device.raw, 12345) };
        let err = device.check("testing").unwrap_err().to_string();
        assert!(geometry.is_null());
        // Embree's own text must reach the message, not just the code.
        assert!(err.contains("invalid geometry type"), "{err}");
        assert!(device.check("again").is_ok(), "errors must be cleared once reported");
    }

    #[test]
    fn flush_denormals_sets_the_calling_threads_mxcsr_only() {
        // Run on a fresh thread so the test harness thread keeps its default MXCSR.
        std::thread::spawn(|| {
            let before = flush_denormals_enabled();
            set_flush_denormals();
            let after = flush_denormals_enabled();
            if cfg!(target_arch = "x86_64") {
                assert!(!before);
                assert!(after);
                // With DAZ, a denormal input behaves as zero.
                let tiny = std::hint::black_box(f32::MIN_POSITIVE / 4.0);
                assert_eq!(std::hint::black_box(tiny * 1.0), 0.0);
            }
        })
        .join()
        .unwrap();
        if cfg!(target_arch = "x86_64") {
            std::thread::spawn(|| assert!(!flush_denormals_enabled())).join().unwrap();
        }
    }
}
