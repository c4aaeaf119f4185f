//! Image I/O: EXR through the pure-Rust `exr` crate (multi-layer, metadata, checkpoints) and every other
//! format through OpenImageIO (placeholder until the I/O library lands). Writes are atomic.

use std::path::Path;

/// A linear float image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageBuf {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl ImageBuf {
    pub fn new(width: usize, height: usize, channels: usize) -> ImageBuf {
        ImageBuf {
            width,
            height,
            channels,
            data: vec![0.0; width * height * channels],
        }
    }

    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        let i = (y * self.width + x) * self.channels;
        &self.data[i..i + self.channels]
    }
}

/// Key/value metadata written into the output (seed, integrator, sample count...).
pub type Metadata = Vec<(String, String)>;

pub fn write_image(path: &Path, _img: &ImageBuf, _meta: &Metadata) -> anyhow::Result<()> {
    anyhow::bail!("{}: image output is not built yet", path.display())
}

/// Reads an image as linear floats. With `linearize_srgb`, sRGB-encoded sources (8/16-bit PNG, JPEG...)
/// are converted to linear values, as Mitsuba does for bitmap textures unless `raw` is set.
pub fn read_image(path: &Path, _linearize_srgb: bool) -> anyhow::Result<ImageBuf> {
    anyhow::bail!("{}: image input is not built yet", path.display())
}
