//! The Embree device (with an error callback whose messages become `anyhow` errors naming the step
//! that failed), scene and geometry handles, mesh upload, packet-width selection, the library version
//! and the flush-to-zero setting Embree wants in every tracing thread.

use super::ffi;
use crate::geometry::TriangleMesh;
use anyhow::{anyhow, bail};
use std::ffi::{c_char, c_void, CStr};
use std::ptr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// Embree silently drops triangles with NaN vertices and reads out of bounds on bad indices, so such
/// meshes are rejected here (see `TriangleMesh::validate`) with the offending element named.
pub(super) fn validate_mesh(index: usize, mesh: &TriangleMesh) -> anyhow::Result<()> {
    mesh.validate(index).map_err(|e| anyhow::anyhow!("Embree: {e}"))
}

pub(super) fn attach_mesh(
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
pub(super) struct Device {
    pub(super) raw: ffi::RTCDevice,
    errors: Box<ErrorSink>,
}

impl Device {
    pub(super) fn new() -> anyhow::Result<Device> {
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
    pub(super) fn check(&self, during: &str) -> anyhow::Result<()> {
        // SAFETY: `raw` is live; this reads and clears the calling thread's error code.
        let code = unsafe { ffi::rtcGetDeviceError(self.raw) };
        let messages = self.errors.take();
        if messages.is_empty() && code == ffi::RTC_ERROR_NONE {
            return Ok(());
        }
        let detail = if messages.is_empty() { error_name(code).to_string() } else { messages.join("; ") };
        Err(anyhow!("Embree error while {during}: {detail}"))
    }

    /// Whether Embree reported an error since the last `check` (one atomic load); debug builds check
    /// it after every query.
    #[cfg(debug_assertions)]
    #[inline]
    pub(super) fn has_errors(&self) -> bool {
        self.errors.any.load(Ordering::Relaxed)
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

pub(super) struct SceneHandle(pub(super) ffi::RTCScene);

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
pub(super) fn choose_packet_width(device: &Device) -> usize {
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
