//! PNG I/O through the pure-Rust `png` crate, used when hslt is built without the `oiio` feature:
//! writes 8-bit sRGB (tagged with an sRGB chunk) and reads 1/2/4/8/16-bit PNG of any colour type.
//! Encoding per the PNG specification (ISO/IEC 15948): sRGB chunk or no gAMA means sRGB.

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use super::{ColorEncoding, ImageBuf, Metadata};

/// Writes `img` (finite, linear) as an 8-bit sRGB PNG with metadata in tEXt chunks.
pub fn write(path: &Path, img: &ImageBuf, meta: &Metadata) -> anyhow::Result<()> {
    let color = match img.channels {
        1 => png::ColorType::Grayscale,
        2 => png::ColorType::GrayscaleAlpha,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        n => anyhow::bail!("{n} channels per pixel cannot be written to PNG"),
    };
    let width =
        u32::try_from(img.width).map_err(|_| anyhow::anyhow!("width {} too large for PNG", img.width))?;
    let height =
        u32::try_from(img.height).map_err(|_| anyhow::anyhow!("height {} too large for PNG", img.height))?;
    let file = File::create(path)?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), width, height);
    encoder.set_color(color);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    for (key, value) in meta {
        // tEXt is Latin-1 only; iTXt carries UTF-8 and is what the PNG spec recommends for it.
        let result = if value.is_ascii() {
            encoder.add_text_chunk(key.clone(), value.clone())
        } else {
            encoder.add_itxt_chunk(key.clone(), value.clone())
        };
        result.map_err(|e| anyhow::anyhow!("metadata key {key:?} cannot be stored in PNG: {e}"))?;
    }
    let mut writer = encoder.write_header()?;
    writer.write_image_data(&img.to_srgb8())?;
    writer.finish()?;
    Ok(())
}

/// Reads a PNG as floats in [0, 1] (not yet linearised) and reports its transfer curve.
pub fn read(path: &Path) -> anyhow::Result<(ImageBuf, ColorEncoding)> {
    let fail = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: cannot read PNG: {e}", path.display());
    let file = File::open(path).map_err(|e| fail(&e))?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    // Expand palettes, low bit depths and tRNS so the output is always Gray/GrayA/RGB/RGBA at 8 or 16 bits.
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(|e| fail(&e))?;
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf).map_err(|e| fail(&e))?;
    let channels = frame.color_type.samples();
    let (width, height) = (frame.width as usize, frame.height as usize);
    let mut img = ImageBuf::new(width, height, channels);
    let row_values = width * channels;
    for y in 0..height {
        let row = &buf[y * frame.line_size..(y + 1) * frame.line_size];
        let out = &mut img.data[y * row_values..(y + 1) * row_values];
        match frame.bit_depth {
            png::BitDepth::Sixteen => {
                for (v, bytes) in out.iter_mut().zip(row.chunks_exact(2)) {
                    *v = f32::from(u16::from_be_bytes([bytes[0], bytes[1]])) / 65535.0;
                }
            }
            _ => {
                for (v, &byte) in out.iter_mut().zip(row) {
                    *v = f32::from(byte) / 255.0;
                }
            }
        }
    }
    let info = reader.info();
    let encoding = match (info.srgb, info.source_gamma) {
        (None, Some(gamma)) => {
            let file_gamma = gamma.into_value();
            // gAMA stores the encoding exponent (e.g. 0.45455); decoding uses its reciprocal.
            if (file_gamma - 1.0).abs() < 1e-3 {
                ColorEncoding::Linear
            } else {
                ColorEncoding::Gamma(1.0 / file_gamma)
            }
        }
        _ => ColorEncoding::Srgb,
    };
    Ok((img, encoding))
}
