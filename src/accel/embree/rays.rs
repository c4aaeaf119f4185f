//! Single-ray queries (`rtcIntersect1`/`rtcOccluded1`) and the conversion of our rays and hits to and
//! from Embree's structs, which the packet kernels share.

use super::{ffi, EmbreeScene};
use crate::accel::Hit;
use crate::geometry::Ray;

impl EmbreeScene {
    /// Closest hit of `ray` in `(tmin, tmax)` (see [`crate::accel::RayQuery::intersect`]).
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

/// `ray` as Embree's struct, or `None` when it cannot hit anything or would be invalid input for
/// Embree (see [`crate::accel::query_interval`]).
// Embree accepts tnear < t <= tfar, and its t carries a few ulps of error (it multiplies by an
// approximate reciprocal: a hit at exactly t = 1 comes back as 1 - 2^-24), so the ends of the interval
// only hold up to that precision. Shadow rays must shrink their segment by a relative epsilon anyway;
// shifting tfar by an ulp here would promise more than Embree keeps.
#[inline]
pub(super) fn rtc_ray(ray: &Ray) -> Option<ffi::RTCRay> {
    let (tnear, tfar) = crate::accel::query_interval(ray)?;
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
pub(super) const EMPTY_RAY: ffi::RTCRay = ffi::RTCRay {
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
pub(super) fn no_hit() -> ffi::RTCHit {
    ffi::RTCHit {
        geomID: ffi::RTC_INVALID_GEOMETRY_ID,
        primID: ffi::RTC_INVALID_GEOMETRY_ID,
        instID: [ffi::RTC_INVALID_GEOMETRY_ID; ffi::RTC_MAX_INSTANCE_LEVEL_COUNT as usize],
        ..Default::default()
    }
}

#[inline]
pub(super) fn hit_of(rayhit: &ffi::RTCRayHit) -> Option<Hit> {
    (rayhit.hit.geomID != ffi::RTC_INVALID_GEOMETRY_ID).then_some(Hit {
        t: rayhit.ray.tfar,
        geom_id: rayhit.hit.geomID,
        prim_id: rayhit.hit.primID,
        u: rayhit.hit.u,
        v: rayhit.hit.v,
    })
}

#[inline]
pub(super) fn coherence_flag(coherent: bool) -> ffi::RTCIntersectContextFlags {
    if coherent {
        ffi::RTC_INTERSECT_CONTEXT_FLAG_COHERENT
    } else {
        ffi::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT
    }
}

/// An intersect context with the given hint and no filter or instance stack: what
/// `rtcInitIntersectContext` builds, written inline so it costs a few stores per query.
#[inline]
pub(super) fn new_context(flags: ffi::RTCIntersectContextFlags) -> ffi::RTCIntersectContext {
    #[allow(clippy::needless_update)]
    ffi::RTCIntersectContext {
        flags,
        filter: None,
        instID: [ffi::RTC_INVALID_GEOMETRY_ID; ffi::RTC_MAX_INSTANCE_LEVEL_COUNT as usize],
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Vec3;

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
}
