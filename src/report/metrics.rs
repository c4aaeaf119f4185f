//! Image error metrics against a reference, in one place for `compare`, the reports and the tests.
//! All are means over pixels and the three colour channels; the default is the relative MSE of the
//! Metropolis literature, which weighs dark and bright regions alike.

use crate::image::ImageBuf;
use anyhow::bail;

/// ε of the relative MSE: keeps black reference pixels from dividing by zero while barely touching
/// pixels brighter than ~0.3 (the usual choice in MLT comparisons is 1e-2 to 1e-3).
pub const DEFAULT_REL_EPSILON: f64 = 1e-2;

/// Every metric of one image against the reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorMetrics {
    /// mean of (x − r)² / (r² + ε)
    pub rel_mse: f64,
    /// sqrt(mean of (x − r)²)
    pub rmse: f64,
    /// mean of |x − r|
    pub mae: f64,
}

/// The metric a report plots (all are written to the CSV).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    RelMse,
    Rmse,
    Mae,
}

impl Metric {
    pub fn parse(name: &str) -> Result<Metric, String> {
        match name {
            "relmse" | "rel-mse" => Ok(Metric::RelMse),
            "rmse" => Ok(Metric::Rmse),
            "mae" => Ok(Metric::Mae),
            other => Err(format!("unknown metric '{other}' (available: relmse, rmse, mae)")),
        }
    }

    /// A label for plot axes and tables.
    pub fn label(self) -> &'static str {
        match self {
            Metric::RelMse => "relative MSE",
            Metric::Rmse => "RMSE",
            Metric::Mae => "mean absolute error",
        }
    }

    pub fn of(self, m: &ErrorMetrics) -> f64 {
        match self {
            Metric::RelMse => m.rel_mse,
            Metric::Rmse => m.rmse,
            Metric::Mae => m.mae,
        }
    }
}

/// The value of colour channel `c` (0..3) of a pixel: grey images repeat their one channel and
/// alpha is never compared.
fn channel(img: &ImageBuf, pixel: usize, c: usize) -> f64 {
    let colour_channels = if img.channels >= 3 { 3 } else { 1 };
    img.data[pixel * img.channels + c.min(colour_channels - 1)] as f64
}

fn check_sizes(img: &ImageBuf, reference: &ImageBuf) -> anyhow::Result<()> {
    if (img.width, img.height) != (reference.width, reference.height) {
        bail!(
            "image is {}x{} but the reference is {}x{}",
            img.width,
            img.height,
            reference.width,
            reference.height
        );
    }
    if img.width == 0 || img.height == 0 {
        bail!("cannot compare empty images");
    }
    Ok(())
}

/// All metrics of `img` against `reference` (same size; RGB, RGBA or grey), with relative-MSE `eps`.
pub fn compute(img: &ImageBuf, reference: &ImageBuf, eps: f64) -> anyhow::Result<ErrorMetrics> {
    check_sizes(img, reference)?;
    let (mut rel, mut sq, mut abs) = (0.0, 0.0, 0.0);
    let pixels = img.width * img.height;
    for p in 0..pixels {
        for c in 0..3 {
            let (x, r) = (channel(img, p, c), channel(reference, p, c));
            let d = x - r;
            rel += d * d / (r * r + eps);
            sq += d * d;
            abs += d.abs();
        }
    }
    let n = (pixels * 3) as f64;
    Ok(ErrorMetrics { rel_mse: rel / n, rmse: (sq / n).sqrt(), mae: abs / n })
}

/// Per-pixel relative squared error, averaged over the colour channels (row-major): the error maps
/// and the choice of zoomed crops in the report.
pub fn relative_error_map(img: &ImageBuf, reference: &ImageBuf, eps: f64) -> anyhow::Result<Vec<f64>> {
    check_sizes(img, reference)?;
    Ok((0..img.width * img.height)
        .map(|p| {
            (0..3)
                .map(|c| {
                    let (x, r) = (channel(img, p, c), channel(reference, p, c));
                    (x - r) * (x - r) / (r * r + eps)
                })
                .sum::<f64>()
                / 3.0
        })
        .collect())
}

/// The image averaged over `block`×`block` tiles (edge tiles average what they hold), colour channels
/// only: error on block means separates bias and low-frequency error from per-pixel noise, which a
/// noisy reference also carries.
pub fn block_means(img: &ImageBuf, block: usize) -> ImageBuf {
    let block = block.max(1);
    let (bw, bh) = (img.width.div_ceil(block), img.height.div_ceil(block));
    let mut out = ImageBuf::new(bw, bh, 3);
    for by in 0..bh {
        for bx in 0..bw {
            let mut sum = [0.0f64; 3];
            let mut n = 0usize;
            for y in by * block..((by + 1) * block).min(img.height) {
                for x in bx * block..((bx + 1) * block).min(img.width) {
                    for (c, s) in sum.iter_mut().enumerate() {
                        *s += channel(img, y * img.width + x, c);
                    }
                    n += 1;
                }
            }
            for (c, s) in sum.iter().enumerate() {
                out.data[(by * bw + bx) * 3 + c] = (s / n as f64) as f32;
            }
        }
    }
    out
}

/// Ratio of block-mean luminance, image over reference, per `block`×`block` tile (row-major, size of
/// [`block_means`]): where a bias sits. Blocks where the reference is black give 1 when the image is
/// black too and +∞ otherwise.
pub fn block_ratio_map(img: &ImageBuf, reference: &ImageBuf, block: usize) -> anyhow::Result<ImageBuf> {
    check_sizes(img, reference)?;
    let (a, r) = (block_means(img, block), block_means(reference, block));
    let mut out = ImageBuf::new(a.width, a.height, 1);
    for (i, v) in out.data.iter_mut().enumerate() {
        let lum = |m: &ImageBuf| (0..3).map(|c| m.data[i * 3 + c] as f64).sum::<f64>();
        let (x, y) = (lum(&a), lum(&r));
        *v = if y > 0.0 {
            (x / y) as f32
        } else if x == 0.0 {
            1.0
        } else {
            f32::INFINITY
        };
    }
    Ok(out)
}

/// A block ratio map as a picture the size of the original image: white at ratio 1, red above, blue
/// below, full colour at a factor of `span` (e.g. 2: red at 2×, blue at ½); black where the ratio is
/// not finite.
pub fn ratio_map_picture(ratio: &ImageBuf, block: usize, width: usize, height: usize, span: f64) -> ImageBuf {
    let mut out = ImageBuf::new(width, height, 3);
    let scale = span.ln().max(1e-6);
    for y in 0..height {
        for x in 0..width {
            let q = ratio.data[(y / block) * ratio.width + x / block] as f64;
            let rgb = if !(q.is_finite() && q > 0.0) {
                [0.0, 0.0, 0.0]
            } else {
                let t = (q.ln() / scale).clamp(-1.0, 1.0);
                if t >= 0.0 {
                    [1.0, 1.0 - t, 1.0 - t]
                } else {
                    [1.0 + t, 1.0 + t, 1.0]
                }
            };
            for (c, v) in rgb.iter().enumerate() {
                // Linear values: the sRGB writer encodes them.
                out.data[(y * width + x) * 3 + c] = crate::image::srgb_to_linear(*v as f32);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn constant(w: usize, h: usize, v: [f32; 3]) -> ImageBuf {
        let mut img = ImageBuf::new(w, h, 3);
        for px in img.data.chunks_mut(3) {
            px.copy_from_slice(&v);
        }
        img
    }

    #[test]
    fn block_ratio_map_finds_the_biased_block() {
        let r = constant(8, 4, [0.5, 0.5, 0.5]);
        let mut a = r.clone();
        // The top-right 4×4 block is 20% bright.
        for y in 0..4 {
            for x in 4..8 {
                for c in 0..3 {
                    a.data[(y * 8 + x) * 3 + c] = 0.6;
                }
            }
        }
        let map = block_ratio_map(&a, &r, 4).unwrap();
        assert_eq!((map.width, map.height, map.channels), (2, 1, 1));
        assert!((map.data[0] - 1.0).abs() < 1e-6 && (map.data[1] - 1.2).abs() < 1e-6, "{:?}", map.data);
        let black = constant(8, 4, [0.0; 3]);
        let zero = block_ratio_map(&black, &black, 4).unwrap();
        assert_eq!(zero.data, vec![1.0, 1.0]);
        assert!(block_ratio_map(&r, &black, 4).unwrap().data[0].is_infinite());
        let pic = ratio_map_picture(&map, 4, 8, 4, 2.0);
        // Ratio 1 is white; 1.2 is reddish (full red, reduced green and blue).
        assert_eq!(pic.pixel(0, 0), &[1.0, 1.0, 1.0]);
        let red = pic.pixel(7, 3);
        assert!(red[0] == 1.0 && red[1] < 1.0 && red[1] == red[2], "{red:?}");
    }

    #[test]
    fn identical_images_have_zero_error() {
        let a = constant(4, 3, [0.2, 0.5, 3.0]);
        assert_eq!(
            compute(&a, &a, DEFAULT_REL_EPSILON).unwrap(),
            ErrorMetrics { rel_mse: 0.0, rmse: 0.0, mae: 0.0 }
        );
    }

    #[test]
    fn grey_reference_is_compared_with_every_colour_channel() {
        let mut grey = ImageBuf::new(2, 2, 1);
        grey.data.fill(1.0);
        let rgb = constant(2, 2, [1.0, 2.0, 1.0]);
        let m = compute(&rgb, &grey, 0.0).unwrap();
        assert!((m.rel_mse - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn sizes_must_match() {
        let err = compute(&constant(2, 2, [0.0; 3]), &constant(2, 3, [0.0; 3]), 0.0).unwrap_err();
        assert!(err.to_string().contains("2x2") && err.to_string().contains("2x3"), "{err}");
    }

    #[test]
    fn block_means_average_each_tile_including_the_partial_edge_tiles() {
        let mut img = ImageBuf::new(3, 2, 3);
        for (p, px) in img.data.chunks_mut(3).enumerate() {
            px.copy_from_slice(&[p as f32, 1.0, 2.0 * p as f32]);
        }
        // pixels 0 1 2 / 3 4 5 in 2×2 tiles: {0,1,3,4} and {2,5}
        let blocks = block_means(&img, 2);
        assert_eq!((blocks.width, blocks.height), (2, 1));
        assert_eq!(blocks.data, vec![2.0, 1.0, 4.0, 3.5, 1.0, 7.0]);
    }
}
