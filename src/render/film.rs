//! The film: per-pixel sums and sample counts, resolved to an image by averaging, plus a splat buffer
//! for estimates that land on arbitrary pixels (light tracing in BDPT, Metropolis chains) and optional
//! named layers (BDPT's per-strategy images). Camera samples are placed by filter importance sampling
//! (see `sensor::rfilter`), so each pixel is a plain mean; splats are spread with the filter itself.

use crate::image::ImageBuf;
use crate::sensor::ReconstructionFilter;
use crate::spectrum::Spectrum;
use glam::Vec2;

/// Per extra layer: pixel sums and splat sums.
type LayerBuffers = (Vec<[f64; 3]>, Vec<[f64; 3]>);

/// A contribution at a continuous film position (pixels, origin top-left), optionally to a layer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splat {
    pub pos: Vec2,
    pub value: Spectrum,
    /// Index of an extra layer (`Film::layer_names`) or `None` for the main image.
    pub layer: Option<u16>,
}

#[derive(Clone, Debug)]
pub struct Film {
    pub width: usize,
    pub height: usize,
    sums: Vec<[f64; 3]>,
    /// Sums of squared sample values, for the per-pixel variance that statistical tests need.
    squares: Vec<[f64; 3]>,
    counts: Vec<u64>,
    splats: Vec<[f64; 3]>,
    /// Factor applied to the splat buffer when resolving: 1/spp for light tracing (one light path per
    /// camera sample), the Metropolis normalisation for chains.
    pub splat_scale: f64,
    layer_names: Vec<String>,
    /// Per layer: pixel sums (divided by the pixel's sample count) and splats (scaled like the main ones).
    layers: Vec<LayerBuffers>,
    filter: SplatFilter,
}

impl Film {
    pub fn new(width: usize, height: usize) -> Film {
        Film::with_filter(width, height, ReconstructionFilter::Box)
    }

    /// A film whose splats are spread with `rfilter`, truncated to the image like camera samples are.
    pub fn with_filter(width: usize, height: usize, rfilter: ReconstructionFilter) -> Film {
        let n = width * height;
        Film {
            width,
            height,
            sums: vec![[0.0; 3]; n],
            squares: vec![[0.0; 3]; n],
            counts: vec![0; n],
            splats: vec![[0.0; 3]; n],
            splat_scale: 1.0,
            layer_names: Vec::new(),
            layers: Vec::new(),
            filter: SplatFilter::new(rfilter, width, height),
        }
    }

    /// Adds an extra output layer; returns its index for `Splat::layer` and `add_layer_sample`.
    pub fn add_layer(&mut self, name: impl Into<String>) -> u16 {
        let n = self.width * self.height;
        self.layer_names.push(name.into());
        self.layers.push((vec![[0.0; 3]; n], vec![[0.0; 3]; n]));
        (self.layers.len() - 1) as u16
    }

    pub fn layer_names(&self) -> &[String] {
        &self.layer_names
    }

    /// Adds one tile's sums and sums of squares (row-major within the tile), each pixel having taken
    /// `samples` samples.
    pub fn add_tile(
        &mut self,
        tile: (usize, usize, usize, usize),
        sums: &[[f64; 3]],
        squares: &[[f64; 3]],
        samples: u32,
    ) {
        let (x0, y0, w, h) = tile;
        for y in 0..h {
            for x in 0..w {
                let i = (y0 + y) * self.width + x0 + x;
                for (acc, v) in self.sums[i].iter_mut().zip(sums[y * w + x]) {
                    *acc += v;
                }
                for (acc, v) in self.squares[i].iter_mut().zip(squares[y * w + x]) {
                    *acc += v;
                }
                self.counts[i] += samples as u64;
            }
        }
    }

    /// Adds a resolved image (same size, RGB) as the mean of `samples` samples of every pixel: a
    /// separately rendered component that the splats then land on (Metropolis integrators' direct
    /// pass), weighted so that films merged later weigh it by the work behind it.
    pub fn add_image_as_samples(&mut self, image: &ImageBuf, samples: u64) {
        assert_eq!((image.width, image.height), (self.width, self.height), "adding an image of another size");
        if samples == 0 {
            return;
        }
        let n = samples as f64;
        for (i, px) in image.data.chunks_exact(image.channels).enumerate() {
            for c in 0..3 {
                let v = px[c.min(image.channels - 1)] as f64;
                self.sums[i][c] += v * n;
                self.squares[i][c] += v * v * n;
            }
            self.counts[i] += samples;
        }
    }

    /// Adds an image (same size, RGB) to the unscaled splat sums.
    pub fn add_splat_image(&mut self, image: &ImageBuf) {
        assert_eq!((image.width, image.height), (self.width, self.height), "adding an image of another size");
        for (acc, px) in self.splats.iter_mut().zip(image.data.chunks_exact(image.channels)) {
            for c in 0..3 {
                acc[c] += px[c.min(image.channels - 1)] as f64;
            }
        }
    }

    /// The pixel means of the camera samples (or added images), without the splats.
    pub fn mean_image(&self) -> ImageBuf {
        let zero = vec![[0.0; 3]; self.splats.len()];
        self.resolve(&self.sums, &zero)
    }

    /// The splat sums as they are, before `splat_scale`.
    pub fn splat_sum_image(&self) -> ImageBuf {
        let mut img = ImageBuf::new(self.width, self.height, 3);
        for (px, s) in img.data.chunks_exact_mut(3).zip(&self.splats) {
            for c in 0..3 {
                px[c] = s[c] as f32;
            }
        }
        img
    }

    /// The sample count every pixel has, when all have the same (the render loop keeps whole passes
    /// only, so a pixel integrator's film always does); `None` for a film mixed otherwise.
    pub fn uniform_count(&self) -> Option<u64> {
        let first = *self.counts.first()?;
        self.counts.iter().all(|&c| c == first).then_some(first)
    }

    /// Adds a value to pixel (x, y) of a layer, as part of that pixel's camera samples.
    pub fn add_layer_sample(&mut self, layer: u16, x: usize, y: usize, value: Spectrum) {
        let acc = &mut self.layers[layer as usize].0[y * self.width + x];
        for (a, v) in acc.iter_mut().zip(value.to_array()) {
            *a += v as f64;
        }
    }

    /// Spreads a splat over the pixels whose (truncated, renormalised) filter covers its position.
    pub fn add_splat(&mut self, splat: &Splat) {
        if !(splat.value.is_finite() && splat.pos.x >= 0.0 && splat.pos.y >= 0.0) {
            return;
        }
        let (width, height) = (self.width, self.height);
        if splat.pos.x >= width as f32 || splat.pos.y >= height as f32 {
            return;
        }
        let target = match splat.layer {
            None => &mut self.splats,
            Some(l) => &mut self.layers[l as usize].1,
        };
        let value = splat.value.as_dvec3();
        self.filter.spread(splat.pos, |x, y, w| {
            let acc = &mut target[y * width + x];
            acc[0] += value.x * w;
            acc[1] += value.y * w;
            acc[2] += value.z * w;
        });
    }

    /// Samples taken in pixel (x, y).
    pub fn count(&self, x: usize, y: usize) -> u64 {
        self.counts[y * self.width + x]
    }

    /// The resolved image: pixel means plus scaled splats.
    pub fn to_image(&self) -> ImageBuf {
        self.resolve(&self.sums, &self.splats)
    }

    /// The resolved extra layers, by name.
    pub fn layer_images(&self) -> Vec<(String, ImageBuf)> {
        self.layer_names
            .iter()
            .zip(&self.layers)
            .map(|(name, (sums, splats))| (name.clone(), self.resolve(sums, splats)))
            .collect()
    }

    fn resolve(&self, sums: &[[f64; 3]], splats: &[[f64; 3]]) -> ImageBuf {
        let mut img = ImageBuf::new(self.width, self.height, 3);
        for (i, ((s, &n), sp)) in sums.iter().zip(&self.counts).zip(splats).enumerate() {
            for c in 0..3 {
                let mean = if n > 0 { s[c] / n as f64 } else { 0.0 };
                img.data[i * 3 + c] = (mean + sp[c] * self.splat_scale) as f32;
            }
        }
        img
    }

    /// Per-pixel variance of the pixel mean (sample variance / n); infinite where n < 2. Covers the
    /// camera samples only: splats have no per-pixel sample count.
    pub fn variance_image(&self) -> ImageBuf {
        let mut img = ImageBuf::new(self.width, self.height, 3);
        for (i, ((s, q), &n)) in self.sums.iter().zip(&self.squares).zip(&self.counts).enumerate() {
            for c in 0..3 {
                img.data[i * 3 + c] = if n >= 2 {
                    let n = n as f64;
                    let mean = s[c] / n;
                    (((q[c] / n - mean * mean) * n / (n - 1.0)).max(0.0) / n) as f32
                } else {
                    f32::INFINITY
                };
            }
        }
        img
    }

    /// Adds another film of the same size (per-thread or per-chain films merged at the end).
    pub fn merge(&mut self, other: &Film) {
        assert_eq!(
            (self.width, self.height),
            (other.width, other.height),
            "merging films of different sizes"
        );
        let add = |a: &mut [[f64; 3]], b: &[[f64; 3]]| {
            for (x, y) in a.iter_mut().zip(b) {
                for c in 0..3 {
                    x[c] += y[c];
                }
            }
        };
        add(&mut self.sums, &other.sums);
        add(&mut self.squares, &other.squares);
        add(&mut self.splats, &other.splats);
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        for ((a, b), (c, d)) in self.layers.iter_mut().zip(&other.layers) {
            add(a, c);
            add(b, d);
        }
    }
}

/// The reconstruction filter as splat weights: camera samples for pixel j are drawn from the filter
/// around j's centre truncated to the image, i.e. from h(q − c_j)/Z_j, so a splat at q must reach pixel
/// j with exactly that weight for light tracing and camera sampling to estimate the same pixel value.
/// All supported filters are separable, so Z_j = Z_x(x)·Z_y(y).
#[derive(Clone, Debug)]
struct SplatFilter {
    rfilter: ReconstructionFilter,
    radius: f32,
    norm_x: Vec<f64>,
    norm_y: Vec<f64>,
}

impl SplatFilter {
    fn new(rfilter: ReconstructionFilter, width: usize, height: usize) -> SplatFilter {
        let radius = rfilter.radius();
        let norm = |n: usize| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    let c = i as f64 + 0.5;
                    let lo = (c - radius as f64).max(0.0);
                    let hi = (c + radius as f64).min(n as f64);
                    integrate(|x| rfilter.eval_1d((x - c) as f32) as f64, lo, hi)
                })
                .collect()
        };
        SplatFilter { rfilter, radius, norm_x: norm(width), norm_y: norm(height) }
    }

    fn spread(&self, pos: Vec2, mut add: impl FnMut(usize, usize, f64)) {
        let r = self.radius;
        let (w, h) = (self.norm_x.len() as i64, self.norm_y.len() as i64);
        // Pixel j is reached when |pos − centre_j| <= r, centre_j = j + 0.5.
        let x0 = ((pos.x - r - 0.5).ceil() as i64).max(0);
        let x1 = ((pos.x + r - 0.5).floor() as i64).min(w - 1);
        let y0 = ((pos.y - r - 0.5).ceil() as i64).max(0);
        let y1 = ((pos.y + r - 0.5).floor() as i64).min(h - 1);
        if matches!(self.rfilter, ReconstructionFilter::Box) {
            // Half-open pixels, so a position on a pixel border lands in exactly one pixel.
            add(pos.x as usize, pos.y as usize, 1.0);
            return;
        }
        for y in y0..=y1 {
            let wy = self.rfilter.eval_1d(pos.y - (y as f32 + 0.5)) as f64 / self.norm_y[y as usize];
            if !(wy > 0.0) {
                continue;
            }
            for x in x0..=x1 {
                let wx = self.rfilter.eval_1d(pos.x - (x as f32 + 0.5)) as f64 / self.norm_x[x as usize];
                if wx > 0.0 {
                    add(x as usize, y as usize, wx * wy);
                }
            }
        }
    }
}

/// Composite Simpson integration; the filters are smooth inside their support, so 256 panels are
/// far below f32 precision.
fn integrate(f: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
    if !(hi > lo) {
        return 0.0;
    }
    let n = 256;
    let h = (hi - lo) / n as f64;
    let mut s = f(lo) + f(hi);
    for i in 1..n {
        s += f(lo + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    s * h / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;

    #[test]
    fn the_film_fits_in_what_the_loader_budgets_per_pixel() {
        let film = Film::new(64, 32);
        let pixels = (film.width * film.height) as u64;
        let buffers = [
            std::mem::size_of_val(film.sums.as_slice()),
            std::mem::size_of_val(film.squares.as_slice()),
            std::mem::size_of_val(film.counts.as_slice()),
            std::mem::size_of_val(film.splats.as_slice()),
        ];
        let film_bytes = buffers.iter().sum::<usize>() as u64;
        let image_bytes = std::mem::size_of_val(film.to_image().data.as_slice()) as u64;
        // The film, the resolved image and one output copy of it.
        let per_pixel = (film_bytes + 2 * image_bytes) / pixels;
        assert!(
            per_pixel <= crate::sensor::FILM_BYTES_PER_PIXEL,
            "a render keeps {per_pixel} bytes per pixel, more than sensor::FILM_BYTES_PER_PIXEL"
        );
    }

    /// Splatting a camera sample's value at positions drawn from each pixel's own truncated filter must
    /// reproduce, on average, what the pixel mean gives: the filter weights are a partition of each
    /// pixel's sampling density. Checked by splatting a constant: every pixel must come out at 1.
    #[test]
    fn splats_of_a_constant_resolve_to_that_constant() {
        for rfilter in [
            ReconstructionFilter::Box,
            ReconstructionFilter::Tent { radius: 1.0 },
            ReconstructionFilter::Gaussian { stddev: 0.5 },
        ] {
            let (w, h) = (7, 5);
            let mut film = Film::with_filter(w, h, rfilter);
            let mut sampler = Sampler::new(3, 0, 0);
            // ~11k splats per pixel: 5% is about five standard deviations.
            let n = 400_000;
            // Uniform positions over the image: density 1/(w h) per unit area, so each pixel gets
            // (w h)·E[weight] = 1 after scaling by w h / n.
            for _ in 0..n {
                let u = sampler.next_2d();
                let pos = Vec2::new(u.x * w as f32, u.y * h as f32);
                film.add_splat(&Splat { pos, value: Spectrum::ONE, layer: None });
            }
            film.splat_scale = (w * h) as f64 / n as f64;
            let img = film.to_image();
            for (i, v) in img.data.iter().enumerate() {
                assert!((v - 1.0).abs() < 0.05, "{rfilter:?}: pixel {} = {v}", i / 3);
            }
        }
    }

    #[test]
    fn an_added_image_is_the_base_the_splats_land_on() {
        let mut film = Film::new(2, 1);
        let mut base = ImageBuf::new(2, 1, 3);
        base.data.copy_from_slice(&[0.25, 0.5, 1.0, 2.0, 0.0, 3.0]);
        film.add_image_as_samples(&base, 1);
        film.add_splat(&Splat { pos: Vec2::new(1.5, 0.5), value: Spectrum::splat(4.0), layer: None });
        film.splat_scale = 0.5;
        let img = film.to_image();
        assert_eq!(img.data, vec![0.25, 0.5, 1.0, 4.0, 2.0, 5.0]);
        assert_eq!(film.count(0, 0), 1);
    }

    #[test]
    fn layers_and_merge_keep_sums_apart() {
        let mut a = Film::new(2, 1);
        let l = a.add_layer("s1t2");
        a.add_tile((0, 0, 2, 1), &[[1.0; 3], [2.0; 3]], &[[1.0; 3], [4.0; 3]], 1);
        a.add_layer_sample(l, 1, 0, Spectrum::splat(0.5));
        let mut b = a.clone();
        b.add_splat(&Splat { pos: Vec2::new(0.5, 0.5), value: Spectrum::splat(3.0), layer: None });
        a.merge(&b);
        let img = a.to_image();
        assert_eq!(img.data[0], (1.0 + 1.0) / 2.0 + 3.0);
        assert_eq!(img.data[3], (2.0 + 2.0) / 2.0);
        let layers = a.layer_images();
        assert_eq!(layers[0].0, "s1t2");
        assert_eq!(layers[0].1.data[3], 1.0 / 2.0);
    }
}
