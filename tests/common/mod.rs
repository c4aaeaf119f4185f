//! Statistical image comparison shared by the reference tests.
//!
//! Two independent renders `a` and `b` of ours (different seeds) give a per-pixel noise estimate,
//! var(a) ≈ (a − b)² / 2. Pixels are averaged over blocks; under the hypothesis "same expectation as
//! the reference", each block's z = (a − ref) / σ is close to standard normal, so Σ z² over blocks
//! follows a χ² law with one degree of freedom per block. A bias shows up as a huge χ², noise does not.
//! σ² also holds the reference's own noise and an allowance for model differences between renderers
//! (stated per test), so the threshold is explicit rather than tuned by eye.

#![allow(dead_code)]

use hslt::image::ImageBuf;

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

/// Box-downsamples an image by an integer factor (to compare a high-resolution reference with a
/// render at lower resolution).
pub fn downsample(img: &ImageBuf, factor: usize) -> ImageBuf {
    let (w, h) = (img.width / factor, img.height / factor);
    let mut out = ImageBuf::new(w, h, 3);
    let blocks = block_means(img, factor, factor);
    for (i, b) in blocks.iter().enumerate() {
        for c in 0..3 {
            out.data[i * 3 + c] = b[c] as f32;
        }
    }
    out
}

/// Compares our renders `a`, `b` (same settings, different seeds) with `reference`.
/// `ref_noise_ratio` is var(reference) / var(a) (e.g. spp_a / spp_ref for the same estimator);
/// `model_tolerance` is a relative allowance for differences between renderers' models.
pub fn compare(
    a: &ImageBuf,
    b: &ImageBuf,
    reference: &ImageBuf,
    block: (usize, usize),
    ref_noise_ratio: f64,
    model_tolerance: f64,
) -> Comparison {
    assert_eq!((a.width, a.height), (reference.width, reference.height), "image sizes differ");
    let (bw, bh) = block;
    let ma = block_means(a, bw, bh);
    let mb = block_means(b, bw, bh);
    let mr = block_means(reference, bw, bh);
    let (mut chi2, mut rel_mse, mut dof) = (0.0, 0.0, 0usize);
    let (mut sum_a, mut sum_r) = (0.0, 0.0);
    for i in 0..ma.len() {
        for c in 0..3 {
            let (va, vb, vr) = (ma[i][c], mb[i][c], mr[i][c]);
            sum_a += va;
            sum_r += vr;
            let noise = (va - vb).powi(2) / 2.0;
            let var = noise * (1.0 + ref_noise_ratio) + (model_tolerance * vr).powi(2) + 1e-8;
            chi2 += (va - vr).powi(2) / var;
            rel_mse += (va - vr).powi(2) / (vr * vr + 1e-3);
            dof += 1;
        }
    }
    Comparison {
        flux_ratio: sum_a / sum_r.max(1e-12),
        block_rel_mse: rel_mse / dof as f64,
        chi2_per_dof: chi2 / dof as f64,
        blocks: ma.len(),
    }
}
