//! Image I/O: EXR through the pure-Rust `exr` crate (multi-layer, metadata, checkpoints) and every
//! other format through OpenImageIO via our C++ shim (or the `png` crate without the `oiio` feature).
//! Writes are atomic (temp file + fsync + rename); sRGB follows IEC 61966-2-1.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::Context;

mod exr_io;
#[cfg(feature = "oiio")]
mod oiio;
#[cfg(not(feature = "oiio"))]
mod png_io;

/// A linear float image, row-major, row 0 at the top, `channels` interleaved values per pixel.
/// Channel layouts: 1 = Y, 2 = Y+A, 3 = RGB, 4 = RGBA. Alpha is straight (not premultiplied) and
/// never sRGB-encoded; readers return the stored values without (un)premultiplying.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageBuf {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl ImageBuf {
    pub fn new(width: usize, height: usize, channels: usize) -> ImageBuf {
        ImageBuf { width, height, channels, data: vec![0.0; width * height * channels] }
    }

    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        let i = (y * self.width + x) * self.channels;
        &self.data[i..i + self.channels]
    }

    pub fn pixel_mut(&mut self, x: usize, y: usize) -> &mut [f32] {
        let i = (y * self.width + x) * self.channels;
        &mut self.data[i..i + self.channels]
    }

    /// Index of the alpha channel in this layout, if there is one.
    pub fn alpha_channel(&self) -> Option<usize> {
        match self.channels {
            2 => Some(1),
            4 => Some(3),
            _ => None,
        }
    }

    /// Checks that the buffer is non-empty, has 1 to 4 channels and `data` matches the size.
    pub fn check_layout(&self) -> anyhow::Result<()> {
        if self.width == 0 || self.height == 0 {
            anyhow::bail!("image is empty ({}x{})", self.width, self.height);
        }
        if !(1..=4).contains(&self.channels) {
            anyhow::bail!("{} channels per pixel (expected 1 to 4)", self.channels);
        }
        let expected = self.width.checked_mul(self.height).and_then(|n| n.checked_mul(self.channels));
        if expected != Some(self.data.len()) {
            anyhow::bail!(
                "pixel buffer holds {} values but {}x{}x{} needs {}",
                self.data.len(),
                self.width,
                self.height,
                self.channels,
                self.width * self.height * self.channels
            );
        }
        Ok(())
    }

    /// Number of NaN or infinite values.
    pub fn count_non_finite(&self) -> usize {
        self.data.iter().filter(|v| !v.is_finite()).count()
    }

    /// Display encoding for 8-bit outputs: colour clamped to [0, 1], sRGB OETF, rounded to the
    /// nearest code; alpha clamped and quantised linearly. NaN maps to 0. Same layout as `self`.
    pub fn to_srgb8(&self) -> Vec<u8> {
        let alpha = self.alpha_channel();
        let quantise = |v: f32| (v * 255.0).round() as u8;
        self.data
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let clamped = if v > 0.0 { v.min(1.0) } else { 0.0 };
                if Some(i % self.channels) == alpha {
                    quantise(clamped)
                } else {
                    quantise(linear_to_srgb(clamped))
                }
            })
            .collect()
    }

    /// Copy with NaN/±Inf replaced by 0, and how many values were replaced.
    fn sanitized(&self) -> (ImageBuf, usize) {
        let mut copy = self.clone();
        let mut replaced = 0;
        for v in &mut copy.data {
            if !v.is_finite() {
                *v = 0.0;
                replaced += 1;
            }
        }
        (copy, replaced)
    }
}

/// Key/value metadata written into the output (seed, integrator, sample count...).
pub type Metadata = Vec<(String, String)>;

/// Metadata key under which writers record how many non-finite values they replaced by 0.
pub const NON_FINITE_KEY: &str = "hslt:nonFiniteReplaced";

/// How the pixel values of a file are encoded, as reported by the reader.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColorEncoding {
    Linear,
    /// IEC 61966-2-1 sRGB transfer curve.
    Srgb,
    /// Pure power law: linear = encoded^gamma.
    Gamma(f32),
}

/// What a write did besides writing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteReport {
    /// NaN/Inf values replaced by 0 (also recorded in the file under [`NON_FINITE_KEY`] when > 0).
    pub non_finite_replaced: usize,
}

/// sRGB OETF (linear → encoded), IEC 61966-2-1 piecewise curve. Not clamped: callers clamp.
pub fn linear_to_srgb(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// sRGB EOTF (encoded → linear), the exact inverse of [`linear_to_srgb`].
pub fn srgb_to_linear(x: f32) -> f32 {
    if x <= 0.040_45 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

/// Output formats chosen by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Exr,
    Png,
    Jpeg,
    Tiff,
    Hdr,
}

const SUPPORTED_OUTPUT: &str = ".exr, .png, .jpg/.jpeg, .tif/.tiff, .hdr";

fn extension_lowercase(path: &Path) -> Option<String> {
    path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase())
}

fn output_format(path: &Path) -> anyhow::Result<Format> {
    let ext = extension_lowercase(path);
    Ok(match ext.as_deref() {
        Some("exr") => Format::Exr,
        Some("png") => Format::Png,
        Some("jpg" | "jpeg") => Format::Jpeg,
        Some("tif" | "tiff") => Format::Tiff,
        Some("hdr") => Format::Hdr,
        _ => anyhow::bail!(
            "{}: unsupported image extension {}; supported: {SUPPORTED_OUTPUT}",
            path.display(),
            ext.map_or_else(|| "(none)".to_string(), |e| format!(".{e}"))
        ),
    })
}

/// The OpenImageIO shim library as this build linked it (`generate-assets` copies it for the package).
#[cfg(feature = "oiio")]
pub fn built_oiio_shim_path() -> &'static Path {
    oiio::built_shim_path()
}

/// Version of the OpenImageIO the shim loads ("2.4.7"), or `None` when built without the `oiio`
/// feature or when the shim library cannot be loaded.
pub fn oiio_version() -> Option<String> {
    #[cfg(feature = "oiio")]
    {
        oiio::version()
    }
    #[cfg(not(feature = "oiio"))]
    {
        None
    }
}

/// Why the OpenImageIO shim cannot be loaded (`None`: it loads, or the build has no `oiio` feature).
pub fn oiio_load_error() -> Option<String> {
    #[cfg(feature = "oiio")]
    {
        oiio::load_error()
    }
    #[cfg(not(feature = "oiio"))]
    {
        None
    }
}

/// Checks before a render that an image can be written at `path`: a known extension, and for the
/// formats OpenImageIO writes, a shim that loads (so that a missing one is an error up front, not
/// after the render).
pub fn check_output_format(path: &Path) -> anyhow::Result<()> {
    let format = output_format(path)?;
    if format != Format::Exr && cfg!(feature = "oiio") {
        if let Some(why) = oiio_load_error() {
            anyhow::bail!("{}: cannot write this format: {why}", path.display());
        }
    }
    Ok(())
}

/// Writes `img` to `path`, format chosen by extension (see [`write_image_with_report`]).
pub fn write_image(path: &Path, img: &ImageBuf, meta: &Metadata) -> anyhow::Result<()> {
    write_image_with_report(path, img, meta).map(|_| ())
}

/// Writes `img` atomically: .exr as float32 through `exr`; .png/.jpg/.tif/.hdr through OpenImageIO
/// (8-bit formats get clamped sRGB, TIFF/HDR linear float); .png through the `png` crate without
/// the `oiio` feature. NaN/Inf are replaced by 0, counted in the report and, when any were found,
/// recorded in the file's metadata under [`NON_FINITE_KEY`].
pub fn write_image_with_report(path: &Path, img: &ImageBuf, meta: &Metadata) -> anyhow::Result<WriteReport> {
    let format = output_format(path)?;
    img.check_layout().with_context(|| format!("{}: cannot write", path.display()))?;
    let (clean, replaced) = img.sanitized();
    let meta = with_non_finite_record(meta, replaced);
    write_atomically(path, |tmp| match format {
        Format::Exr => exr_io::write_layers_to(tmp, &[("", &clean, None)], &meta),
        _ => write_non_exr(tmp, format, &clean, &meta),
    })?;
    Ok(WriteReport { non_finite_replaced: replaced })
}

#[cfg(feature = "oiio")]
fn write_non_exr(tmp: &Path, _format: Format, img: &ImageBuf, meta: &Metadata) -> anyhow::Result<()> {
    oiio::write(tmp, img, meta)
}

#[cfg(not(feature = "oiio"))]
fn write_non_exr(tmp: &Path, format: Format, img: &ImageBuf, meta: &Metadata) -> anyhow::Result<()> {
    match format {
        Format::Png => png_io::write(tmp, img, meta),
        other => {
            anyhow::bail!("writing {other:?} needs the `oiio` feature (this build only writes .exr and .png)")
        }
    }
}

/// Writes a multi-part EXR: the first layer is the main image (its name may be empty only when it
/// is the only layer), the others e.g. "strategy.s2t1". All layers must have the same size;
/// metadata goes on the first part. Atomic, and non-finite values are handled as in `write_image`.
pub fn write_exr_layers(
    path: &Path,
    layers: &[(&str, &ImageBuf)],
    meta: &Metadata,
) -> anyhow::Result<WriteReport> {
    let parts: Vec<(&str, &ImageBuf, Option<&[&str]>)> =
        layers.iter().map(|&(n, img)| (n, img, None)).collect();
    write_exr_parts(path, &parts, meta)
}

/// As `write_exr_layers`, with channel names per layer where they are not the default R,G,B (or Y
/// for one channel): e.g. X,Y,Z for normals, Z for depth.
pub fn write_exr_parts(
    path: &Path,
    layers: &[(&str, &ImageBuf, Option<&[&str]>)],
    meta: &Metadata,
) -> anyhow::Result<WriteReport> {
    if output_format(path)? != Format::Exr {
        anyhow::bail!("{}: multi-layer output must have the .exr extension", path.display());
    }
    let mut cleaned = Vec::with_capacity(layers.len());
    let mut replaced = 0;
    for &(name, img, channels) in layers {
        img.check_layout().with_context(|| format!("{}: layer {name:?}", path.display()))?;
        let (clean, count) = img.sanitized();
        replaced += count;
        cleaned.push((name, clean, channels));
    }
    let meta = with_non_finite_record(meta, replaced);
    let refs: Vec<exr_io::ExrPart> = cleaned.iter().map(|(n, img, c)| (*n, img, *c)).collect();
    write_atomically(path, |tmp| exr_io::write_layers_to(tmp, &refs, &meta))?;
    Ok(WriteReport { non_finite_replaced: replaced })
}

/// String metadata of an EXR written by [`write_image`]/[`write_exr_layers`] (e.g. to resume from
/// a checkpoint), sorted by key, without decoding pixels.
pub fn read_exr_metadata(path: &Path) -> anyhow::Result<Metadata> {
    exr_io::read_metadata(path)
}

/// Every part of an EXR as (layer name, pixels); see [`read_image`] for the channel choice.
pub fn read_exr_layers(path: &Path) -> anyhow::Result<Vec<(String, ImageBuf)>> {
    exr_io::read_layers(path)
}

/// Reads an image as linear floats. With `linearize_srgb`, sRGB-encoded sources (8/16-bit PNG, JPEG...)
/// are converted to linear values, as Mitsuba does for bitmap textures unless `raw` is set.
/// EXR (always linear) is read with `exr`: RGB(A) or Y(A) channels, half or float. Other formats go
/// through OpenImageIO with all their channels (only PNG without the `oiio` feature).
pub fn read_image(path: &Path, linearize_srgb: bool) -> anyhow::Result<ImageBuf> {
    if extension_lowercase(path).as_deref() == Some("exr") {
        return exr_io::read(path);
    }
    let (mut img, encoding) = read_non_exr(path)?;
    if linearize_srgb {
        linearize(&mut img, encoding);
    }
    Ok(img)
}

#[cfg(feature = "oiio")]
fn read_non_exr(path: &Path) -> anyhow::Result<(ImageBuf, ColorEncoding)> {
    if !path.is_file() {
        anyhow::bail!("{}: no such image file", path.display());
    }
    oiio::read(path)
}

#[cfg(not(feature = "oiio"))]
fn read_non_exr(path: &Path) -> anyhow::Result<(ImageBuf, ColorEncoding)> {
    match extension_lowercase(path).as_deref() {
        Some("png") => png_io::read(path),
        _ => anyhow::bail!(
            "{}: reading this format needs the `oiio` feature (this build reads only .exr and .png)",
            path.display()
        ),
    }
}

/// Converts encoded colour channels to linear in place; alpha is left as is.
fn linearize(img: &mut ImageBuf, encoding: ColorEncoding) {
    let alpha = img.alpha_channel();
    let channels = img.channels;
    let decode: Box<dyn Fn(f32) -> f32> = match encoding {
        ColorEncoding::Linear => return,
        ColorEncoding::Srgb => Box::new(srgb_to_linear),
        ColorEncoding::Gamma(g) => Box::new(move |x: f32| x.max(0.0).powf(g)),
    };
    for (i, v) in img.data.iter_mut().enumerate() {
        if Some(i % channels) != alpha {
            *v = decode(*v);
        }
    }
}

fn with_non_finite_record(meta: &Metadata, replaced: usize) -> Metadata {
    let mut meta = meta.clone();
    if replaced > 0 {
        meta.retain(|(k, _)| k != NON_FINITE_KEY);
        meta.push((NON_FINITE_KEY.to_string(), replaced.to_string()));
    }
    meta
}

/// Temporary sibling of `target`: hidden, unique per process and call, and keeping the extension
/// because OpenImageIO picks the format from it.
fn temp_path_for(target: &Path) -> anyhow::Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let file_name = target
        .file_name()
        .ok_or_else(|| anyhow::anyhow!("{}: not a file path", target.display()))?
        .to_string_lossy();
    let ext = target.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let name = format!(".{file_name}.tmp-{}-{n}{ext}", std::process::id());
    Ok(match target.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.join(name),
        _ => PathBuf::from(name),
    })
}

/// Runs `write` on a temporary file next to `target`, fsyncs it and renames it over `target`, so
/// readers never see a partial image. On any error the temporary file is removed and `target` is
/// left untouched.
fn write_atomically(target: &Path, write: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
    let tmp = temp_path_for(target)?;
    // create_new both reserves the name and gives a clear error for a missing/readonly directory.
    fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .with_context(|| format!("{}: cannot create temporary file {}", target.display(), tmp.display()))?;
    let result = (|| -> anyhow::Result<()> {
        write(&tmp)?;
        fs::File::open(&tmp).and_then(|f| f.sync_all()).context("cannot flush the written data to disk")?;
        fs::rename(&tmp, target).context("cannot move the temporary file into place")?;
        Ok(())
    })();
    match result {
        Ok(()) => {
            // Persist the rename itself; not all filesystems allow syncing a directory, and the data
            // is already complete either way, so a failure here is not an error.
            if let Some(dir) = tmp.parent().filter(|d| !d.as_os_str().is_empty()) {
                if let Ok(d) = fs::File::open(dir) {
                    let _ = d.sync_all();
                }
            }
            Ok(())
        }
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(e.context(format!("{}: cannot write image", target.display())))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_curves_are_inverse_and_continuous() {
        for i in 0..=1000 {
            let x = i as f32 / 1000.0;
            let round_trip = srgb_to_linear(linear_to_srgb(x));
            assert!((round_trip - x).abs() < 1e-5, "x={x} -> {round_trip}");
        }
        // The two pieces meet at the breakpoint (IEC 61966-2-1 constants are continuous to ~1e-7).
        let below = linear_to_srgb(0.003_130_8);
        let above = 1.055 * 0.003_130_8f32.powf(1.0 / 2.4) - 0.055;
        assert!((below - above).abs() < 1e-6);
        assert_eq!(linear_to_srgb(0.0), 0.0);
        assert!((linear_to_srgb(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
    }

    #[test]
    fn srgb8_clamps_rounds_and_keeps_alpha_linear() {
        let img = ImageBuf {
            width: 2,
            height: 1,
            channels: 4,
            data: vec![-1.0, 2.0, f32::NAN, 0.5, 0.2, 0.0, 1.0, 0.25],
        };
        let bytes = img.to_srgb8();
        // linear 0.2 encodes to 0.48453, i.e. code 123.55.
        assert_eq!(bytes, vec![0, 255, 0, 128, 124, 0, 255, 64]);
    }

    #[test]
    fn output_format_by_extension() {
        assert_eq!(output_format(Path::new("a/b.EXR")).unwrap(), Format::Exr);
        assert_eq!(output_format(Path::new("x.jpeg")).unwrap(), Format::Jpeg);
        assert_eq!(output_format(Path::new("x.tif")).unwrap(), Format::Tiff);
        let err = output_format(Path::new("out.bmp")).unwrap_err().to_string();
        assert!(err.contains("out.bmp") && err.contains(".bmp") && err.contains(".exr"), "{err}");
        let err = output_format(Path::new("noext")).unwrap_err().to_string();
        assert!(err.contains("(none)"), "{err}");
    }

    #[test]
    fn temp_path_is_hidden_sibling_with_same_extension() {
        let tmp = temp_path_for(Path::new("/some/dir/render.png")).unwrap();
        assert_eq!(tmp.parent(), Some(Path::new("/some/dir")));
        let name = tmp.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with(".render.png.tmp-") && name.ends_with(".png"), "{name}");
        assert_ne!(tmp, temp_path_for(Path::new("/some/dir/render.png")).unwrap());
    }

    #[test]
    fn linearize_skips_alpha() {
        let mut img = ImageBuf { width: 1, height: 1, channels: 2, data: vec![0.5, 0.5] };
        linearize(&mut img, ColorEncoding::Srgb);
        assert!((img.data[0] - 0.214_041).abs() < 1e-5);
        assert_eq!(img.data[1], 0.5);
        linearize(&mut img, ColorEncoding::Gamma(2.0));
        assert!((img.data[0] - 0.214_041f32.powi(2)).abs() < 1e-6);
    }
}
