//! Safe wrappers over the OpenImageIO C++ shim (`oiio_shim.cpp`): read any format OIIO knows as
//! float pixels, write PNG/JPEG/TIFF/HDR (8-bit targets get sRGB-encoded values). The only module in
//! `image/` with `unsafe`; every C string and buffer crossing the boundary is owned on this side.

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::os::unix::ffi::OsStrExt;
use std::path::Path;

use super::{ColorEncoding, ImageBuf, Metadata};

/// Mirrors `HsltImageInfo` in oiio_shim.cpp.
#[repr(C)]
#[derive(Default)]
struct RawImageInfo {
    width: c_int,
    height: c_int,
    channels: c_int,
    encoding: c_int,
    gamma: f32,
}

extern "C" {
    fn hslt_oiio_free_string(s: *mut c_char);
    fn hslt_oiio_version() -> *mut c_char;
    fn hslt_oiio_open(path: *const c_char, info: *mut RawImageInfo, err: *mut *mut c_char) -> *mut c_void;
    fn hslt_oiio_read(handle: *mut c_void, out: *mut f32, out_len: usize, err: *mut *mut c_char) -> c_int;
    fn hslt_oiio_close(handle: *mut c_void);
    #[allow(clippy::too_many_arguments)]
    fn hslt_oiio_write(
        path: *const c_char,
        data: *const f32,
        width: c_int,
        height: c_int,
        channels: c_int,
        keys: *const *const c_char,
        values: *const *const c_char,
        n_meta: c_int,
        err: *mut *mut c_char,
    ) -> c_int;
}

/// Takes ownership of a string allocated by the shim and returns it as a Rust `String`.
fn take_shim_string(ptr: *mut c_char) -> Option<String> {
    if ptr.is_null() {
        return None;
    }
    // SAFETY: a non-null pointer from the shim is a NUL-terminated malloc'd string that nobody else
    // references; we copy it and free it exactly once with the shim's matching deallocator.
    unsafe {
        let text = CStr::from_ptr(ptr).to_string_lossy().into_owned();
        hslt_oiio_free_string(ptr);
        Some(text)
    }
}

fn error_text(err: *mut c_char) -> String {
    take_shim_string(err).unwrap_or_else(|| "unknown OpenImageIO error".to_string())
}

fn path_to_cstring(path: &Path) -> anyhow::Result<CString> {
    CString::new(path.as_os_str().as_bytes())
        .map_err(|_| anyhow::anyhow!("{}: path contains a NUL byte", path.display()))
}

fn to_c_int(value: usize, what: &str) -> anyhow::Result<c_int> {
    c_int::try_from(value).map_err(|_| anyhow::anyhow!("{what} {value} is too large for OpenImageIO"))
}

/// Version of the linked OpenImageIO library, e.g. "2.4.7".
pub fn version() -> Option<String> {
    // SAFETY: no arguments; the returned pointer (or null) is handled by take_shim_string.
    take_shim_string(unsafe { hslt_oiio_version() })
}

/// Closes the shim's ImageInput when dropped, including on early error returns.
struct InputHandle(*mut c_void);

impl Drop for InputHandle {
    fn drop(&mut self) {
        // SAFETY: the handle came from a successful hslt_oiio_open and is closed only here, once.
        unsafe { hslt_oiio_close(self.0) }
    }
}

/// The most decoded samples a byte of an image file can plausibly stand for (see `read`).
const MAX_SAMPLES_PER_FILE_BYTE: u64 = 65_536;

/// Reads subimage 0 of `path`: float pixels with all of the file's channels, and how they are encoded.
pub fn read(path: &Path) -> anyhow::Result<(ImageBuf, ColorEncoding)> {
    let c_path = path_to_cstring(path)?;
    let mut info = RawImageInfo::default();
    let mut err: *mut c_char = std::ptr::null_mut();
    // SAFETY: c_path is NUL-terminated and outlives the call; info and err are valid out-pointers.
    let handle = unsafe { hslt_oiio_open(c_path.as_ptr(), &mut info, &mut err) };
    if handle.is_null() {
        anyhow::bail!("{}: {}", path.display(), error_text(err));
    }
    let handle = InputHandle(handle);

    let dims = [info.width, info.height, info.channels];
    if dims.iter().any(|&d| d <= 0) {
        anyhow::bail!(
            "{}: invalid image size {}x{} with {} channels",
            path.display(),
            info.width,
            info.height,
            info.channels
        );
    }
    let (width, height, channels) = (info.width as usize, info.height as usize, info.channels as usize);
    let len = width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(channels))
        .ok_or_else(|| anyhow::anyhow!("{}: image is too large", path.display()))?;
    // The header's size is the file's word: a lying one must be an error, not an aborted allocation
    // or gigabytes zeroed for a file of a few hundred bytes (a fuzzing find). No image codec packs
    // more than ~8 000 samples into a byte (deflate's 1032:1 on a 1-bit PNG), so a header claiming
    // over 65 536 per byte of the file (plus room for tiny files) is lying.
    let file_len = std::fs::metadata(path).map(|m| m.len()).unwrap_or(u64::MAX);
    if len as u64 > file_len.saturating_mul(MAX_SAMPLES_PER_FILE_BYTE).saturating_add(1 << 24) {
        anyhow::bail!(
            "{}: the header declares a {width}x{height} image with {channels} channels, more than a file \
             of {file_len} bytes can hold",
            path.display()
        );
    }
    let what = format!("{}: a {width}x{height} image with {channels} channels", path.display());
    let data = crate::resources::try_filled_vec(len, 0.0, &what).map_err(anyhow::Error::msg)?;
    let mut img = ImageBuf { width, height, channels, data };
    // SAFETY: the handle is open; img.data has exactly `len` floats, which the shim checks against
    // the image size before writing; err is a valid out-pointer.
    let status = unsafe { hslt_oiio_read(handle.0, img.data.as_mut_ptr(), len, &mut err) };
    if status != 0 {
        anyhow::bail!("{}: {}", path.display(), error_text(err));
    }
    let encoding = match info.encoding {
        1 => ColorEncoding::Srgb,
        2 => ColorEncoding::Gamma(info.gamma),
        _ => ColorEncoding::Linear,
    };
    Ok((img, encoding))
}

/// Writes `img` (linear, finite values) to `path` in the format OIIO associates with its extension.
pub fn write(path: &Path, img: &ImageBuf, meta: &Metadata) -> anyhow::Result<()> {
    let c_path = path_to_cstring(path)?;
    if img.data.len() != img.width * img.height * img.channels {
        anyhow::bail!(
            "{}: pixel buffer does not match {}x{}x{}",
            path.display(),
            img.width,
            img.height,
            img.channels
        );
    }
    let width = to_c_int(img.width, "width")?;
    let height = to_c_int(img.height, "height")?;
    let channels = to_c_int(img.channels, "channel count")?;
    let mut owned = Vec::with_capacity(meta.len() * 2);
    for (key, value) in meta {
        let k = CString::new(key.as_str())
            .map_err(|_| anyhow::anyhow!("{}: metadata key {key:?} contains a NUL byte", path.display()))?;
        let v = CString::new(value.as_str()).map_err(|_| {
            anyhow::anyhow!("{}: metadata value of {key:?} contains a NUL byte", path.display())
        })?;
        owned.push((k, v));
    }
    let keys: Vec<*const c_char> = owned.iter().map(|(k, _)| k.as_ptr()).collect();
    let values: Vec<*const c_char> = owned.iter().map(|(_, v)| v.as_ptr()).collect();
    let n_meta = to_c_int(keys.len(), "metadata count")?;
    let mut err: *mut c_char = std::ptr::null_mut();
    // SAFETY: all pointers refer to live, NUL-terminated strings or to img.data, which holds exactly
    // width*height*channels floats (checked above); the shim only reads them during the call.
    let status = unsafe {
        hslt_oiio_write(
            c_path.as_ptr(),
            img.data.as_ptr(),
            width,
            height,
            channels,
            keys.as_ptr(),
            values.as_ptr(),
            n_meta,
            &mut err,
        )
    };
    if status != 0 {
        anyhow::bail!("{}: {}", path.display(), error_text(err));
    }
    Ok(())
}
