//! Statistical image comparison shared by the reference tests.
//!
//! Our film records every pixel's sample variance, so the variance of a block mean is known from
//! thousands of samples (not guessed from a second render). Under the hypothesis "same expectation as
//! the reference", each block's z = (ours − ref) / σ is close to standard normal, so Σ z² over blocks
//! follows a χ² law with one degree of freedom per block, mean 1 per degree of freedom. A bias shows
//! up as a large χ², noise does not. σ² also holds the reference's own noise (as a ratio to ours) and
//! an allowance for model differences between renderers (stated per test), so every threshold is
//! explicit rather than tuned by eye.

#![allow(dead_code)]

use hslt::image::ImageBuf;
use std::path::{Path, PathBuf};

/// The public test scenes beside the repository (`../shared/scenes`, as on CI), or the folder named
/// by `HSLT_SHARED_SCENES`. Missing scenes fail the test rather than skip it.
pub fn shared_scenes() -> PathBuf {
    let dir = std::env::var_os("HSLT_SHARED_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes"));
    assert!(
        dir.join("cornell-box/scene.xml").is_file(),
        "shared scenes not found at {} (set HSLT_SHARED_SCENES)",
        dir.display()
    );
    dir
}

pub struct Comparison {
    /// mean(ours) / mean(reference) over the whole image, luminance-like (channel average).
    pub flux_ratio: f64,
    /// Relative MSE of the block means: mean over blocks of (a − ref)² / (ref² + 1e-3).
    pub block_rel_mse: f64,
    /// χ² statistic per degree of freedom (≈ 1 when unbiased).
    pub chi2_per_dof: f64,
    pub blocks: usize,
}

/// Block-averages a 3-channel image with `bw × bh` blocks (partial blocks at the edges are dropped).
pub fn block_means(img: &ImageBuf, bw: usize, bh: usize) -> Vec<[f64; 3]> {
    let (nx, ny) = (img.width / bw, img.height / bh);
    let mut out = vec![[0.0; 3]; nx * ny];
    for by in 0..ny {
        for bx in 0..nx {
            let acc = &mut out[by * nx + bx];
            for y in by * bh..(by + 1) * bh {
                for x in bx * bw..(bx + 1) * bw {
                    let p = img.pixel(x, y);
                    for c in 0..3 {
                        acc[c] += p[c.min(img.channels - 1)] as f64;
                    }
                }
            }
            for v in acc.iter_mut() {
                *v /= (bw * bh) as f64;
            }
        }
    }
    out
}

/// Compares our render `a` (with per-pixel variance of the mean `var_a`) with `reference`, over the
/// rows `rows` of the image. `ref_noise_ratio` is var(reference) / var(a) (e.g. spp_a / spp_ref for
/// the same estimator); `model_tolerance` is a relative allowance for differences between renderers.
pub fn compare(
    a: &ImageBuf,
    var_a: &ImageBuf,
    reference: &ImageBuf,
    block: (usize, usize),
    rows: std::ops::Range<usize>,
    ref_noise_ratio: f64,
    model_tolerance: f64,
) -> Comparison {
    assert_eq!((a.width, a.height), (reference.width, reference.height), "image sizes differ");
    let (bw, bh) = block;
    let n = (bw * bh) as f64;
    let ma = block_means(a, bw, bh);
    // Mean of the pixel variances over a block, divided by the pixel count: variance of the block mean.
    let va: Vec<[f64; 3]> = block_means(var_a, bw, bh).iter().map(|v| v.map(|x| x / n)).collect();
    let mr = block_means(reference, bw, bh);
    let nx = a.width / bw;
    let (mut chi2, mut rel_mse, mut dof) = (0.0, 0.0, 0usize);
    let (mut sum_a, mut sum_r) = (0.0, 0.0);
    for i in 0..ma.len() {
        let by = i / nx;
        if by * bh < rows.start || (by + 1) * bh > rows.end {
            continue;
        }
        for c in 0..3 {
            let (x, vr) = (ma[i][c], mr[i][c]);
            sum_a += x;
            sum_r += vr;
            let var = va[i][c] * (1.0 + ref_noise_ratio) + (model_tolerance * vr).powi(2) + 1e-10;
            chi2 += (x - vr).powi(2) / var;
            rel_mse += (x - vr).powi(2) / (vr * vr + 1e-3);
            dof += 1;
        }
    }
    Comparison {
        flux_ratio: sum_a / sum_r.max(1e-12),
        block_rel_mse: rel_mse / dof as f64,
        chi2_per_dof: chi2 / dof as f64,
        blocks: dof / 3,
    }
}

/// Renders `runs` independent images (seeds 1..=runs) of `spp` samples each and returns their mean
/// and a per-pixel variance image whose block means give, for `block`, the variance of the block mean
/// estimated from the spread between runs. Integrators that splat (BDPT, Metropolis) cannot report
/// per-pixel variance from their film, and splats correlate neighbouring pixels, so the spread of
/// whole-block means between runs is the honest measure. With `runs` runs the χ² terms follow a
/// squared Student t with runs − 1 degrees of freedom: mean (runs − 1)/(runs − 3), not 1.
pub fn render_runs(
    scene: &hslt::scene::Scene,
    kind: hslt::registry::IntegratorKind,
    spp: u32,
    runs: u64,
    block: (usize, usize),
) -> (ImageBuf, ImageBuf) {
    let images: Vec<ImageBuf> = (1..=runs)
        .map(|seed| {
            let (img, stats) = hslt::cli::render_scene(scene, kind, spp, seed);
            assert_eq!(stats.invalid_samples, 0, "{}: NaN/Inf samples", kind.name());
            img
        })
        .collect();
    let (w, h) = (images[0].width, images[0].height);
    let mut mean = ImageBuf::new(w, h, 3);
    for img in &images {
        for (m, v) in mean.data.iter_mut().zip(&img.data) {
            *m += v / runs as f32;
        }
    }
    let (bw, bh) = block;
    let per_run: Vec<Vec<[f64; 3]>> = images.iter().map(|img| block_means(img, bw, bh)).collect();
    let nx = w / bw;
    let mut var_img = ImageBuf::new(w, h, 3);
    for b in 0..per_run[0].len() {
        for c in 0..3 {
            let m = per_run.iter().map(|r| r[b][c]).sum::<f64>() / runs as f64;
            let var_run = per_run.iter().map(|r| (r[b][c] - m).powi(2)).sum::<f64>() / (runs - 1) as f64;
            // `compare` divides block-averaged pixel variances by the pixel count.
            let pixel_value = var_run / runs as f64 * (bw * bh) as f64;
            let (bx, by) = (b % nx, b / nx);
            for y in by * bh..(by + 1) * bh {
                for x in bx * bw..(bx + 1) * bw {
                    var_img.data[(y * w + x) * 3 + c] = pixel_value as f32;
                }
            }
        }
    }
    (mean, var_img)
}
pub mod mlt;
