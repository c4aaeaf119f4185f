//! Helpers of the Metropolis tests: MLT noise is correlated between pixels and mutations, so their
//! statistics compare block means across independent runs (different seeds) rather than pixels.

use hslt::image::ImageBuf;
use hslt::integrators::Bdpt;
use hslt::render::DepthLimits;
use hslt::scene::Scene;

/// The BDPT a scene's integrator settings describe (what seeds and regrows the chains' paths).
pub fn bdpt(scene: &Scene) -> Bdpt {
    let limits = DepthLimits::of_scene(scene);
    Bdpt::new(limits, scene.integrator.hide_emitters)
}

/// Mean and standard error of the mean.
pub fn mean_se(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

pub fn image_mean(img: &ImageBuf) -> f64 {
    img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64
}

/// Block means (4 × 4 pixels, channel-averaged) of an image.
pub fn blocks(img: &ImageBuf) -> Vec<f64> {
    let (bw, nx, ny) = (4, img.width / 4, img.height / 4);
    let mut out = vec![0.0; nx * ny];
    for y in 0..ny * bw {
        for x in 0..nx * bw {
            let p = img.pixel(x, y);
            out[(y / bw) * nx + x / bw] += (p[0] + p[1] + p[2]) as f64 / (3.0 * (bw * bw) as f64);
        }
    }
    out
}

/// Σ_j (ā_j − b̄_j)² / Σ_j (s²_a,j / K_a + s²_b,j / K_b) over blocks j, the bars means over the K
/// independent runs of each set and s² their spread: about 1 when both sets have the same
/// expectation, larger with a bias.
pub fn discrepancy(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let stats = |runs: &[Vec<f64>], j: usize| {
        let col: Vec<f64> = runs.iter().map(|r| r[j]).collect();
        let (m, se) = mean_se(&col);
        (m, se * se)
    };
    let (mut num, mut den) = (0.0, 0.0);
    for j in 0..a[0].len() {
        let ((ma, va), (mb, vb)) = (stats(a, j), stats(b, j));
        num += (ma - mb).powi(2);
        den += va + vb;
    }
    num / den
}
