//! Safe wrappers over the OpenImageIO C++ shim (`oiio_shim.cpp`, built as `libhslt_oiio.so` and
//! opened on first use): read any format OIIO knows as float pixels, write PNG/JPEG/TIFF/HDR (8-bit
//! targets get sRGB-encoded values). The only module in `image/` with `unsafe`; every C string and
//! buffer crossing the boundary is owned on this side.

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

type FreeString = unsafe extern "C" fn(s: *mut c_char);
type Version = unsafe extern "C" fn() -> *mut c_char;
type Open =
    unsafe extern "C" fn(path: *const c_char, info: *mut RawImageInfo, err: *mut *mut c_char) -> *mut c_void;
type Read =
    unsafe extern "C" fn(handle: *mut c_void, out: *mut f32, out_len: usize, err: *mut *mut c_char) -> c_int;
type Close = unsafe extern "C" fn(handle: *mut c_void);
type Write = unsafe extern "C" fn(
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

/// The shim's entry points, from the shared library `libhslt_oiio.so` opened on first use: linking
/// OpenImageIO into the binary loaded its 250-odd dependencies into every process (0.2–0.5 s of
/// start-up, about 125 MB of memory; docs/benchmarks.md), though only PNG/JPEG/TIFF/HDR images and
/// non-EXR textures need it.
struct Shim {
    free_string: FreeString,
    version: Version,
    open: Open,
    read: Read,
    close: Close,
    write: Write,
    /// Keeps the library mapped for as long as the function pointers above are used (the process).
    _library: libloading::Library,
}

/// File name of the shim library.
const SHIM_FILE: &str = "libhslt_oiio.so";

/// Where the shim is looked for: `$HSLT_OIIO_SHIM` alone when set; else `../lib/hslt/` beside the
/// executable's directory (an installed `/usr/bin/hslt` finds `/usr/lib/hslt/`), then the build's
/// own output directory.
fn shim_candidates() -> Vec<std::path::PathBuf> {
    if let Some(path) = std::env::var_os("HSLT_OIIO_SHIM") {
        return vec![path.into()];
    }
    let mut candidates = Vec::new();
    if let Some(bin_dir) = std::env::current_exe().ok().and_then(|exe| exe.parent().map(Path::to_path_buf)) {
        candidates.push(bin_dir.join("../lib/hslt").join(SHIM_FILE));
    }
    candidates.push(built_shim_path().to_path_buf());
    candidates
}

/// The shim as the build script linked it (the package copies it to /usr/lib/hslt/).
pub fn built_shim_path() -> &'static Path {
    Path::new(env!("HSLT_OIIO_SHIM_BUILT"))
}

fn load_shim() -> Result<Shim, String> {
    let candidates = shim_candidates();
    let Some(path) = candidates.iter().find(|p| p.is_file()) else {
        let looked: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
        return Err(format!(
            "OpenImageIO support ({SHIM_FILE}) not found; looked at {} (set HSLT_OIIO_SHIM to its path)",
            looked.join(", ")
        ));
    };
    // SAFETY: the file is our shim, built from oiio_shim.cpp by this crate's build script; loading
    // it runs only OpenImageIO's and the C++ runtime's initialisers. Each symbol is looked up with
    // the exact signature of its extern "C" definition in oiio_shim.cpp (mirrored by the types
    // above), and the pointers are used only while `_library` keeps the library mapped.
    unsafe {
        let library = libloading::Library::new(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let symbol_error = |e: libloading::Error| format!("{}: {e}", path.display());
        Ok(Shim {
            free_string: *library.get::<FreeString>(b"hslt_oiio_free_string\0").map_err(symbol_error)?,
            version: *library.get::<Version>(b"hslt_oiio_version\0").map_err(symbol_error)?,
            open: *library.get::<Open>(b"hslt_oiio_open\0").map_err(symbol_error)?,
            read: *library.get::<Read>(b"hslt_oiio_read\0").map_err(symbol_error)?,
            close: *library.get::<Close>(b"hslt_oiio_close\0").map_err(symbol_error)?,
            write: *library.get::<Write>(b"hslt_oiio_write\0").map_err(symbol_error)?,
            _library: library,
        })
    }
}

/// The shim, loaded on first use (`Err`: why it cannot be, the same message on every call).
fn shim() -> anyhow::Result<&'static Shim> {
    static SHIM: std::sync::OnceLock<Result<Shim, String>> = std::sync::OnceLock::new();
    SHIM.get_or_init(load_shim).as_ref().map_err(|e| anyhow::anyhow!("{e}"))
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
        (shim().expect("a shim string comes from a loaded shim").free_string)(ptr);
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

/// Why the shim cannot be loaded, or `None` when it can.
pub fn load_error() -> Option<String> {
    shim().err().map(|e| e.to_string())
}

/// Version of the OpenImageIO library the shim loads, e.g. "2.4.7"; `None` if it cannot be loaded.
pub fn version() -> Option<String> {
    let shim = shim().ok()?;
    // SAFETY: no arguments; the returned pointer (or null) is handled by take_shim_string.
    take_shim_string(unsafe { (shim.version)() })
}

/// Closes the shim's ImageInput when dropped, including on early error returns.
struct InputHandle(*mut c_void, &'static Shim);

impl Drop for InputHandle {
    fn drop(&mut self) {
        // SAFETY: the handle came from a successful hslt_oiio_open and is closed only here, once.
        unsafe { (self.1.close)(self.0) }
    }
}

/// The most decoded samples a byte of an image file can plausibly stand for (see `read`).
const MAX_SAMPLES_PER_FILE_BYTE: u64 = 65_536;

/// Reads subimage 0 of `path`: float pixels with all of the file's channels, and how they are encoded.
pub fn read(path: &Path) -> anyhow::Result<(ImageBuf, ColorEncoding)> {
    let c_path = path_to_cstring(path)?;
    let shim = shim()?;
    let mut info = RawImageInfo::default();
    let mut err: *mut c_char = std::ptr::null_mut();
    // SAFETY: c_path is NUL-terminated and outlives the call; info and err are valid out-pointers.
    let handle = unsafe { (shim.open)(c_path.as_ptr(), &mut info, &mut err) };
    if handle.is_null() {
        anyhow::bail!("{}: {}", path.display(), error_text(err));
    }
    let handle = InputHandle(handle, shim);

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
    let status = unsafe { (shim.read)(handle.0, img.data.as_mut_ptr(), len, &mut err) };
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
    let shim = shim()?;
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
        (shim.write)(
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
