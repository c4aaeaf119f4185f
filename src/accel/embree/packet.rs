//! Batched queries: SIMD packets (`rtcIntersect4/8/16`, the width chosen per CPU) with a coherence hint
//! per packet, which the Newton corrector's ray bundles use, and Embree's stream API for `hslt bench rays`.

use super::rays::{coherence_flag, hit_of, new_context, no_hit, rtc_ray, EMPTY_RAY};
use super::{ffi, EmbreeScene};
use crate::accel::Hit;
use crate::geometry::{Ray, Vec3};
use std::ffi::c_int;

impl EmbreeScene {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
