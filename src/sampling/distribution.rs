//! Piecewise-constant 1D distribution (a normalised CDF) for discrete choices such as
//! picking a light or a triangle in proportion to power or area.

#[derive(Clone, Debug)]
pub struct Distribution1D {
    cdf: Vec<f64>,
    total: f64,
}

impl Distribution1D {
    /// Builds from non-negative weights; returns `None` when all weights are zero or any is invalid.
    pub fn new(weights: &[f64]) -> Option<Distribution1D> {
        let mut cdf = Vec::with_capacity(weights.len() + 1);
        let mut sum = 0.0f64;
        cdf.push(0.0);
        for &w in weights {
            if !w.is_finite() || w < 0.0 {
                return None;
            }
            sum += w;
            cdf.push(sum);
        }
        if sum <= 0.0 {
            return None;
        }
        for c in cdf.iter_mut() {
            *c /= sum;
        }
        Some(Distribution1D { cdf, total: sum })
    }

    pub fn len(&self) -> usize {
        self.cdf.len() - 1
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn total(&self) -> f64 {
        self.total
    }

    /// Probability of choosing entry `i`.
    pub fn pmf(&self, i: usize) -> f32 {
        (self.cdf[i + 1] - self.cdf[i]) as f32
    }

    /// Picks an index with probability proportional to its weight; also returns `u` rescaled to [0,1)
    /// within the chosen interval, so one random number can be reused.
    pub fn sample(&self, u: f32) -> (usize, f32) {
        let n = self.len();
        if n == 1 {
            // One entry (a scene's only light): the interval is [0, 1) itself.
            return (0, u.clamp(0.0, 1.0));
        }
        let u = u as f64;
        // First index whose upper CDF bound exceeds u, skipping zero-weight entries. Few entries (a
        // light's triangles, a scene's lights) are counted without branches: the choice is random, so
        // a binary search's branches mispredict half the time.
        let upper = &self.cdf[1..];
        let mut idx = if n <= 16 {
            upper.iter().map(|&c| usize::from(c <= u)).sum()
        } else {
            upper.partition_point(|&c| c <= u)
        };
        idx = idx.min(n - 1);
        while idx + 1 < n && self.cdf[idx + 1] == self.cdf[idx] {
            idx += 1;
        }
        let lo = self.cdf[idx];
        let width = self.cdf[idx + 1] - lo;
        let rescaled = if width > 0.0 { ((u - lo) / width).clamp(0.0, 1.0 - f64::EPSILON) } else { 0.0 };
        (idx, rescaled as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_follow_weights() {
        let d = Distribution1D::new(&[1.0, 0.0, 3.0]).unwrap();
        let mut counts = [0usize; 3];
        let n = 40_000;
        for i in 0..n {
            let (k, r) = d.sample((i as f32 + 0.5) / n as f32);
            assert!((0.0..1.0).contains(&r));
            counts[k] += 1;
        }
        assert_eq!(counts[1], 0);
        assert!((counts[0] as f64 / n as f64 - 0.25).abs() < 1e-3);
        assert!((d.pmf(2) - 0.75).abs() < 1e-6);
        assert!(Distribution1D::new(&[0.0, 0.0]).is_none());
        assert!(Distribution1D::new(&[f64::NAN]).is_none());
    }

    #[test]
    fn counting_and_binary_search_choose_the_same_entries() {
        // Up to 16 entries are counted, more are searched; both must give the first entry whose upper
        // bound exceeds u, never one of zero weight, and the same rescaled u.
        // Runs of zeros inside and at the end; the first entry is positive so one entry is valid.
        let pattern = [0.5, 0.0, 0.0, 2.0, 1.0, 0.0, 3.0, 0.0];
        for n in [1, 2, 5, 8, 16, 17, 40] {
            let weights: Vec<f64> = (0..n).map(|i| pattern[i % pattern.len()]).collect();
            let d = Distribution1D::new(&weights).unwrap();
            for k in 0..4096 {
                let u = k as f32 / 4096.0;
                let (idx, r) = d.sample(u);
                let expected = (0..n).find(|&i| d.cdf[i + 1] > u as f64).unwrap();
                assert_eq!(idx, expected, "n = {n}, u = {u}");
                assert!(weights[idx] > 0.0);
                let lo = d.cdf[idx];
                let want = ((u as f64 - lo) / (d.cdf[idx + 1] - lo)).clamp(0.0, 1.0 - f64::EPSILON) as f32;
                assert_eq!(r, want, "n = {n}, u = {u}");
            }
        }
    }
}
