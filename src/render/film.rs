//! The film: per-pixel sums and sample counts, resolved to an image by averaging. Samples are placed
//! by filter importance sampling (see `sensor::rfilter`), so each pixel is a plain mean.

use crate::image::ImageBuf;

#[derive(Clone, Debug)]
pub struct Film {
    pub width: usize,
    pub height: usize,
    sums: Vec<[f64; 3]>,
    /// Sums of squared sample values, for the per-pixel variance that statistical tests need.
    squares: Vec<[f64; 3]>,
    counts: Vec<u64>,
}

impl Film {
    pub fn new(width: usize, height: usize) -> Film {
        let n = width * height;
        Film { width, height, sums: vec![[0.0; 3]; n], squares: vec![[0.0; 3]; n], counts: vec![0; n] }
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

    /// Samples taken in pixel (x, y).
    pub fn count(&self, x: usize, y: usize) -> u64 {
        self.counts[y * self.width + x]
    }

    /// The averaged image (pixels without samples are black).
    pub fn to_image(&self) -> ImageBuf {
        let mut img = ImageBuf::new(self.width, self.height, 3);
        for (i, (s, &n)) in self.sums.iter().zip(&self.counts).enumerate() {
            if n > 0 {
                for (out, v) in img.data[i * 3..i * 3 + 3].iter_mut().zip(s) {
                    *out = (v / n as f64) as f32;
                }
            }
        }
        img
    }

    /// Per-pixel variance of the pixel mean (sample variance / n); infinite where n < 2.
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
}
