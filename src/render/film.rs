//! The film: per-pixel sums and sample counts, resolved to an image by averaging. Samples are placed
//! by filter importance sampling (see `sensor::rfilter`), so each pixel is a plain mean.

use crate::image::ImageBuf;

#[derive(Clone, Debug)]
pub struct Film {
    pub width: usize,
    pub height: usize,
    sums: Vec<[f64; 3]>,
    counts: Vec<u64>,
}

impl Film {
    pub fn new(width: usize, height: usize) -> Film {
        Film {
            width,
            height,
            sums: vec![[0.0; 3]; width * height],
            counts: vec![0; width * height],
        }
    }

    /// Adds one tile's sums (row-major within the tile), each pixel having taken `samples` samples.
    pub fn add_tile(
        &mut self,
        x0: usize,
        y0: usize,
        w: usize,
        h: usize,
        sums: &[[f64; 3]],
        samples: u32,
    ) {
        for y in 0..h {
            for x in 0..w {
                let i = (y0 + y) * self.width + x0 + x;
                for (acc, v) in self.sums[i].iter_mut().zip(sums[y * w + x]) {
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
}
