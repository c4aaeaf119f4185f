//! `hslt error`: the error of finished renders against a reference, the numbers `compare` reports
//! but for images made elsewhere (separate runs, other seeds, other renderers). With two references
//! (independent renders of the same scene) it compares against their mean and prints the mean's own
//! noise, so an error near that floor is read as such.

use crate::image::{read_exr_metadata, read_image, ImageBuf};
use crate::report::metrics::{self, block_means, ErrorMetrics};
use crate::report::DEFAULT_REL_EPSILON;
use anyhow::{bail, Context};
use clap::Args;
use std::path::{Path, PathBuf};

/// Arguments of `hslt error`.
#[derive(Args, Debug)]
pub struct ErrorArgs {
    /// Images to measure (EXR, or anything OpenImageIO reads; 8-bit images are linearised).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// The reference image; given twice (two independent renders), their mean is the reference.
    #[arg(long, required = true, num_args = 1)]
    pub reference: Vec<PathBuf>,
    /// ε of the relative MSE, mean of (x − r)² / (r² + ε).
    #[arg(long, default_value_t = DEFAULT_REL_EPSILON)]
    pub epsilon: f64,
    /// Also the relative MSE of N×N block means (low-frequency error and bias, less of the noise).
    #[arg(long, value_name = "N", default_value_t = 8)]
    pub block: usize,
    /// Write the ratio of block-mean luminance (image / reference) over --block tiles, to find where a
    /// bias sits: an EXR holds the ratios, one value per tile at the image's size; a PNG shows them
    /// white at 1, red above, blue below (full colour at --ratio-span). Needs exactly one image.
    #[arg(long, value_name = "FILE")]
    pub ratio_map: Option<PathBuf>,
    /// The ratio that --ratio-map's PNG shows in full red (and its inverse in full blue).
    #[arg(long, value_name = "R", default_value_t = 2.0)]
    pub ratio_span: f64,
}

fn read(path: &Path) -> anyhow::Result<ImageBuf> {
    read_image(path, true).with_context(|| format!("cannot read {}", path.display()))
}

/// The metadata value `key` of an EXR written by `hslt render`, or "-".
fn meta_value(path: &Path, key: &str) -> String {
    read_exr_metadata(path)
        .ok()
        .and_then(|meta| meta.into_iter().find(|(k, _)| k == key).map(|(_, v)| v))
        .unwrap_or_else(|| "-".into())
}

/// The share of the summed per-pixel relative squared error that the worst 1% of pixels carry: near
/// 0.01 the error is spread evenly (noise everywhere), near 1 it sits in a few highlights or fireflies.
fn worst_percent_share(map: &[f64]) -> f64 {
    let total: f64 = map.iter().sum();
    if !(total > 0.0) {
        return 0.0;
    }
    let mut sorted = map.to_vec();
    sorted.sort_unstable_by(|a, b| b.total_cmp(a));
    let worst = map.len().div_ceil(100);
    sorted[..worst].iter().sum::<f64>() / total
}

fn mean_luminance(img: &ImageBuf) -> f64 {
    let colour = if img.channels >= 3 { 3 } else { 1 };
    let pixels = img.width * img.height;
    let sum: f64 = (0..pixels)
        .map(|p| (0..colour).map(|c| img.data[p * img.channels + c] as f64).sum::<f64>() / colour as f64)
        .sum();
    sum / pixels.max(1) as f64
}

/// Averages two references of the same size into a three-channel image.
fn average(a: &ImageBuf, b: &ImageBuf, names: (&Path, &Path)) -> anyhow::Result<ImageBuf> {
    if (a.width, a.height) != (b.width, b.height) {
        bail!(
            "the references differ in size: {} is {}x{}, {} is {}x{}",
            names.0.display(),
            a.width,
            a.height,
            names.1.display(),
            b.width,
            b.height
        );
    }
    let mut out = ImageBuf::new(a.width, a.height, 3);
    for p in 0..a.width * a.height {
        for c in 0..3 {
            let get = |img: &ImageBuf| img.data[p * img.channels + c.min(img.channels.min(3) - 1)];
            out.data[p * 3 + c] = 0.5 * (get(a) + get(b));
        }
    }
    Ok(out)
}

pub fn run(args: ErrorArgs) -> anyhow::Result<i32> {
    if !(args.epsilon >= 0.0 && args.epsilon.is_finite()) {
        bail!("--epsilon must be a finite number ≥ 0, got {}", args.epsilon);
    }
    if args.block == 0 {
        bail!("--block must be at least 1");
    }
    if args.ratio_map.is_some() && args.images.len() != 1 {
        bail!("--ratio-map needs exactly one image, got {}", args.images.len());
    }
    if !(args.ratio_span > 1.0 && args.ratio_span.is_finite()) {
        bail!("--ratio-span must be a finite number above 1, got {}", args.ratio_span);
    }
    let reference = match args.reference.as_slice() {
        [one] => read(one)?,
        [a, b] => {
            let (ia, ib) = (read(a)?, read(b)?);
            let mean = average(&ia, &ib, (a, b))?;
            // Two independent renders differ by twice their variance; their mean carries half of one.
            let halves = metrics::compute(&ia, &ib, args.epsilon)?;
            println!(
                "reference: mean of {} and {}; their relative MSE {:.3e}, so the mean's own noise is about {:.1e}",
                a.display(),
                b.display(),
                halves.rel_mse,
                halves.rel_mse / 4.0
            );
            mean
        }
        more => bail!("--reference takes one or two images, got {}", more.len()),
    };
    let reference_blocks = block_means(&reference, args.block);
    println!("reference mean {:.5}", mean_luminance(&reference));
    let block_header = format!("rel MSE {0}×{0}", args.block);
    println!(
        "| image | integrator | seed | spp | rel MSE | {block_header} | worst 1% | RMSE | MAE | mean |\n|---|---|---|---|---|---|---|---|---|---|"
    );
    for path in &args.images {
        let img = read(path)?;
        let ErrorMetrics { rel_mse, rmse, mae } = metrics::compute(&img, &reference, args.epsilon)
            .with_context(|| format!("{} against the reference", path.display()))?;
        let blocks = metrics::compute(&block_means(&img, args.block), &reference_blocks, args.epsilon)?;
        let worst = worst_percent_share(&metrics::relative_error_map(&img, &reference, args.epsilon)?);
        println!(
            "| {} | {} | {} | {} | {:.3e} | {:.2e} | {:.2} | {:.4e} | {:.4e} | {:.5} |",
            path.display(),
            meta_value(path, "hslt.integrator"),
            meta_value(path, "hslt.seed"),
            meta_value(path, "hslt.spp"),
            rel_mse,
            blocks.rel_mse,
            worst,
            rmse,
            mae,
            mean_luminance(&img)
        );
        if let Some(out) = &args.ratio_map {
            write_ratio_map(out, &img, &reference, args.block, args.ratio_span)
                .with_context(|| format!("cannot write the ratio map {}", out.display()))?;
        }
    }
    Ok(0)
}

/// Writes the block ratio map of `img` against `reference` and prints its extreme tiles.
fn write_ratio_map(
    out: &Path,
    img: &ImageBuf,
    reference: &ImageBuf,
    block: usize,
    span: f64,
) -> anyhow::Result<()> {
    let ratio = metrics::block_ratio_map(img, reference, block)?;
    let (w, h) = (img.width, img.height);
    let is_exr = out.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    let picture = if is_exr {
        let mut full = ImageBuf::new(w, h, 1);
        for y in 0..h {
            for x in 0..w {
                full.data[y * w + x] = ratio.data[(y / block) * ratio.width + x / block];
            }
        }
        full
    } else {
        metrics::ratio_map_picture(&ratio, block, w, h, span)
    };
    let meta = vec![("hslt.ratioMapBlock".to_string(), block.to_string())];
    crate::image::write_image(out, &picture, &meta)?;
    let mut tiles: Vec<(usize, f32)> = ratio.data.iter().copied().enumerate().collect();
    tiles.sort_by(|a, b| (b.1.ln().abs()).total_cmp(&a.1.ln().abs()));
    let listed: Vec<String> = tiles
        .iter()
        .take(5)
        .map(|&(i, q)| format!("({}, {}) {q:.3}", (i % ratio.width) * block, (i / ratio.width) * block))
        .collect();
    println!(
        "ratio map {} ({block}×{block} tiles); farthest from 1 (tile origin x, y: ratio): {}",
        out.display(),
        listed.join(", ")
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::worst_percent_share;

    #[test]
    fn worst_percent_share_tells_spread_error_from_outliers() {
        let even = vec![2.0; 1000];
        assert!((worst_percent_share(&even) - 0.01).abs() < 1e-12);
        let mut one_firefly = vec![1e-3; 1000];
        one_firefly[417] = 100.0;
        // The worst ten hold the firefly and nine others: 100.009 of 100.999.
        assert!((worst_percent_share(&one_firefly) - 100.009 / 100.999).abs() < 1e-12);
        // 150 pixels: the worst 1% is rounded up to two pixels.
        let mut ramp: Vec<f64> = (1..=150).map(f64::from).collect();
        ramp.reverse();
        assert!((worst_percent_share(&ramp) - (150.0 + 149.0) / (150.0 * 151.0 / 2.0)).abs() < 1e-12);
        assert_eq!(worst_percent_share(&[0.0; 10]), 0.0);
    }
}
