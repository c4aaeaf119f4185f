//! OpenEXR I/O through the pure-Rust `exr` crate: float32 output with string metadata, multi-part
//! ("multi-layer") files for per-strategy images, and reading of any flat EXR (half/float, RGB or Y).
//! Follows the OpenEXR 2 file layout: one header per part, string attributes typed `string`.

use std::path::Path;

use anyhow::Context;
use exr::prelude::*;

use super::{ImageBuf, Metadata};

/// Standard OpenEXR attribute names with a non-string type or a structural role; a string
/// attribute with one of these names would confuse readers, so they are refused as metadata keys.
const RESERVED_NAMES: &[&str] = &[
    "tiles",
    "name",
    "type",
    "version",
    "chunkCount",
    "maxSamplesPerPixel",
    "channels",
    "compression",
    "dataWindow",
    "displayWindow",
    "lineOrder",
    "pixelAspectRatio",
    "screenWindowCenter",
    "screenWindowWidth",
    "whiteLuminance",
    "adoptedNeutral",
    "xDensity",
    "utcOffset",
    "longitude",
    "latitude",
    "altitude",
    "focus",
    "expTime",
    "aperture",
    "isoSpeed",
    "envmap",
    "keyCode",
    "timeCode",
    "framesPerSecond",
    "multiView",
    "worldToCamera",
    "worldToNDC",
    "deepImageState",
    "originalDataWindow",
    "dwaCompressionLevel",
    "preview",
    "chromaticities",
    "near",
    "far",
    "fieldOfViewHorizontal",
    "fieldOfViewVertical",
];

/// Standard string attributes that the `exr` crate keeps in dedicated `LayerAttributes` fields
/// rather than in `other`; metadata with these keys is routed through those fields both ways.
fn text_field<'a>(attrs: &'a mut LayerAttributes, key: &str) -> Option<&'a mut Option<Text>> {
    Some(match key {
        "owner" => &mut attrs.owner,
        "comments" => &mut attrs.comments,
        "capDate" => &mut attrs.capture_date,
        "software" => &mut attrs.software_name,
        "renderingTransform" => &mut attrs.rendering_transform_name,
        "lookModTransform" => &mut attrs.look_modification_transform_name,
        "wrapmodes" => &mut attrs.wrap_mode_name,
        "view" => &mut attrs.view_name,
        _ => return None,
    })
}

const TEXT_FIELD_KEYS: [&str; 8] = [
    "owner",
    "comments",
    "capDate",
    "software",
    "renderingTransform",
    "lookModTransform",
    "wrapmodes",
    "view",
];

/// EXR strings are byte strings; we store UTF-8 and decode UTF-8 (falling back to Latin-1, the
/// encoding the `exr` crate assumes, for files written by other tools).
fn text_from_str(s: &str) -> Text {
    Text::from_slice_unchecked(s.as_bytes())
}

fn text_to_string(text: &Text) -> String {
    match std::str::from_utf8(text.bytes()) {
        Ok(s) => s.to_string(),
        Err(_) => text.bytes().iter().map(|&b| b as char).collect(),
    }
}

/// Channel names for an interleaved buffer with `channels` components.
fn channel_names(channels: usize) -> anyhow::Result<&'static [&'static str]> {
    Ok(match channels {
        1 => &["Y"],
        2 => &["Y", "A"],
        3 => &["R", "G", "B"],
        4 => &["R", "G", "B", "A"],
        n => anyhow::bail!("{n} channels per pixel cannot be written to EXR (expected 1 to 4)"),
    })
}

fn layer_channels(img: &ImageBuf, names: Option<&[&str]>) -> anyhow::Result<AnyChannels<FlatSamples>> {
    let names = match names {
        Some(names) if names.len() == img.channels => names,
        Some(names) => anyhow::bail!("{} channel names for {} channels", names.len(), img.channels),
        None => channel_names(img.channels)?,
    };
    let pixels = img.width * img.height;
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for (c, name) in names.iter().enumerate() {
        let plane: Vec<f32> = (0..pixels).map(|p| img.data[p * img.channels + c]).collect();
        list.push(AnyChannel::new(*name, FlatSamples::F32(plane)));
    }
    Ok(AnyChannels::sort(list))
}

fn apply_metadata(attrs: &mut LayerAttributes, meta: &Metadata) -> anyhow::Result<()> {
    let mut seen = std::collections::HashSet::new();
    for (key, value) in meta {
        if key.is_empty() {
            anyhow::bail!("metadata key must not be empty (value {value:?})");
        }
        if !seen.insert(key.as_str()) {
            anyhow::bail!("metadata key {key:?} appears twice");
        }
        if RESERVED_NAMES.contains(&key.as_str()) {
            anyhow::bail!("metadata key {key:?} is a reserved OpenEXR attribute name");
        }
        match text_field(attrs, key) {
            Some(field) => *field = Some(text_from_str(value)),
            None => {
                attrs.other.insert(text_from_str(key), AttributeValue::Text(text_from_str(value)));
            }
        }
    }
    Ok(())
}

/// Builds the in-memory EXR: one part per layer, metadata on the first part.
fn build_image(
    layers: &[ExrPart],
    meta: &Metadata,
) -> anyhow::Result<Image<Layers<AnyChannels<FlatSamples>>>> {
    let (_, main, _) = layers.first().ok_or_else(|| anyhow::anyhow!("no layers to write"))?;
    if main.width == 0 || main.height == 0 {
        anyhow::bail!("image is empty ({}x{})", main.width, main.height);
    }
    let mut names = std::collections::HashSet::new();
    let mut parts = Vec::with_capacity(layers.len());
    for (index, (name, img, channels)) in layers.iter().enumerate() {
        img.check_layout().with_context(|| format!("layer {name:?}"))?;
        if (img.width, img.height) != (main.width, main.height) {
            anyhow::bail!(
                "layer {name:?} is {}x{} but the main image is {}x{}",
                img.width,
                img.height,
                main.width,
                main.height
            );
        }
        let mut attrs = if layers.len() > 1 {
            // Multi-part files need a distinct, non-empty name on every part.
            if name.is_empty() {
                anyhow::bail!("layer {index} has an empty name; every layer of a multi-layer EXR needs one");
            }
            if !names.insert(*name) {
                anyhow::bail!("layer name {name:?} is used twice");
            }
            LayerAttributes::named(text_from_str(name))
        } else {
            let mut attrs = LayerAttributes::default();
            if !name.is_empty() {
                attrs.layer_name = Some(text_from_str(name));
            }
            attrs
        };
        if index == 0 {
            apply_metadata(&mut attrs, meta)?;
        }
        parts.push(Layer::new(
            (img.width, img.height),
            attrs,
            Encoding::SMALL_LOSSLESS,
            layer_channels(img, *channels).with_context(|| format!("layer {name:?}"))?,
        ));
    }
    let attributes = ImageAttributes::new(IntegerBounds::from_dimensions((main.width, main.height)));
    Ok(Image::from_layers(attributes, parts))
}

/// Writes the layers as one EXR file at `path` (not atomic by itself; `super` wraps it).
/// One part to write: its name, pixels and channel names (`None`: R,G,B(,A) or Y(,A) by count).
pub(super) type ExrPart<'a> = (&'a str, &'a ImageBuf, Option<&'a [&'a str]>);

pub(super) fn write_layers_to(path: &Path, layers: &[ExrPart], meta: &Metadata) -> anyhow::Result<()> {
    let image = build_image(layers, meta)?;
    image.write().to_file(path).map_err(|e| anyhow::anyhow!("EXR encoding failed: {e}"))
}

/// Picks the colour channels of a flat part: `R,G,B` (+`A`) or `Y` (+`A`), either bare or all with
/// the same `prefix.` (single-part layered files name channels like `diffuse.R`). Bare names win.
fn pick_channels(names: &[String]) -> Option<Vec<usize>> {
    let find = |wanted: &str| names.iter().position(|n| n == wanted);
    let mut prefixes: Vec<&str> = vec![""];
    for name in names {
        if let Some((prefix, _)) = name.rsplit_once('.') {
            if !prefixes.contains(&prefix) {
                prefixes.push(prefix);
            }
        }
    }
    for &prefix in &prefixes {
        let full = |c: &str| {
            if prefix.is_empty() {
                c.to_string()
            } else {
                format!("{prefix}.{c}")
            }
        };
        let alpha = find(&full("A"));
        if let (Some(r), Some(g), Some(b)) = (find(&full("R")), find(&full("G")), find(&full("B"))) {
            return Some([Some(r), Some(g), Some(b), alpha].into_iter().flatten().collect());
        }
        // Auxiliary layers: normals (X, Y, Z) and depth (Z), as `--aov` writes them.
        if let (Some(x), Some(y), Some(z)) = (find(&full("X")), find(&full("Y")), find(&full("Z"))) {
            return Some(vec![x, y, z]);
        }
        if let Some(y) = find(&full("Y")) {
            return Some([Some(y), alpha].into_iter().flatten().collect());
        }
    }
    // A depth layer alone (`Z`), only when no prefix holds colour: a bare Z beside `diffuse.R/G/B`
    // is that image's depth, not the image.
    prefixes
        .iter()
        .find_map(|prefix| find(&if prefix.is_empty() { "Z".into() } else { format!("{prefix}.Z") }))
        .map(|z| vec![z])
}

fn sample_as_f32(samples: &FlatSamples, index: usize) -> f32 {
    match samples {
        FlatSamples::F16(v) => v[index].to_f32(),
        FlatSamples::F32(v) => v[index],
        FlatSamples::U32(v) => v[index] as f32,
    }
}

/// Converts one decoded part into an interleaved buffer, naming `path` and the part in errors.
fn part_to_buf(path: &Path, layer: &Layer<AnyChannels<FlatSamples>>) -> anyhow::Result<(String, ImageBuf)> {
    let name = layer.attributes.layer_name.as_ref().map(text_to_string).unwrap_or_default();
    let names: Vec<String> = layer.channel_data.list.iter().map(|c| text_to_string(&c.name)).collect();
    let picked = pick_channels(&names).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: EXR part {name:?} has no R,G,B or Y channels (found: {})",
            path.display(),
            names.join(", ")
        )
    })?;
    let (width, height) = (layer.size.width(), layer.size.height());
    let channels = picked.len();
    let mut img = ImageBuf::new(width, height, channels);
    for (c, &source) in picked.iter().enumerate() {
        let samples = &layer.channel_data.list[source].sample_data;
        for p in 0..width * height {
            img.data[p * channels + c] = sample_as_f32(samples, p);
        }
    }
    Ok((name, img))
}

/// Reads the first part of an EXR as linear floats: RGB, RGBA, Y or YA depending on the file.
/// The data window is returned as the image (as OIIO's `read_image` and Mitsuba do).
pub fn read(path: &Path) -> anyhow::Result<ImageBuf> {
    check_declared_size(path, true)?;
    let image = read_first_flat_layer_from_file(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read EXR: {e}", path.display()))?;
    Ok(part_to_buf(path, &image.layer_data)?.1)
}

/// Reads every part of an EXR (name, pixels), with channels picked as in [`read`].
pub fn read_layers(path: &Path) -> anyhow::Result<Vec<(String, ImageBuf)>> {
    check_declared_size(path, false)?;
    let image = read_all_flat_layers_from_file(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read EXR: {e}", path.display()))?;
    image.layer_data.iter().map(|layer| part_to_buf(path, layer)).collect()
}

/// Refuses a file whose header declares more pixels than this process can hold, before the exr crate
/// allocates its sample buffers from the header's word (a lying data window aborted the process on
/// the failed allocation: 49 such inputs in one fuzzing run). Counts the decoded samples (4 bytes
/// each at most) and our converted copy of them; `first_only` as for `read`.
fn check_declared_size(path: &Path, first_only: bool) -> anyhow::Result<()> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| anyhow::anyhow!("{}: cannot read EXR header: {e}", path.display()))?;
    let parts = if first_only { &meta.headers[..meta.headers.len().min(1)] } else { &meta.headers[..] };
    let mut samples = 0u64;
    for header in parts {
        let size = header.layer_size;
        let pixels = (size.width() as u64).saturating_mul(size.height() as u64);
        samples = samples.saturating_add(pixels.saturating_mul(header.channels.list.len() as u64));
    }
    let what = format!("{}: the image its header declares", path.display());
    crate::resources::check_fits(samples.saturating_mul(8), &what).map_err(anyhow::Error::msg)
}

/// Reads the string attributes of the first part (where `write_image`/`write_exr_layers` put the
/// metadata) without decoding any pixels. Non-string attributes are skipped.
pub fn read_metadata(path: &Path) -> anyhow::Result<Metadata> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| anyhow::anyhow!("{}: cannot read EXR header: {e}", path.display()))?;
    let header =
        meta.headers.first().ok_or_else(|| anyhow::anyhow!("{}: EXR file has no header", path.display()))?;
    let mut attrs = header.own_attributes.clone();
    let mut out: Metadata = Vec::new();
    for key in TEXT_FIELD_KEYS {
        if let Some(Some(text)) = text_field(&mut attrs, key) {
            out.push((key.to_string(), text_to_string(text)));
        }
    }
    for (name, value) in &attrs.other {
        if let AttributeValue::Text(text) = value {
            out.push((text_to_string(name), text_to_string(text)));
        }
    }
    // HashMap order is arbitrary; sorting makes the result deterministic.
    out.sort();
    Ok(out)
}
