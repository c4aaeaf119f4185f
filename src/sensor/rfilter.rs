//! Reconstruction filters, applied by filter importance sampling: each camera sample's offset from the
//! pixel centre is drawn from the filter itself, so every sample has weight one and pixels stay
//! independent (deterministic under any thread count). For the positive filters Mitsuba offers this has
//! the same expectation as its splatting, ∫ f L / ∫ f.

use crate::props::{Props, SceneError};
use crate::sampling::special::{erf64, erfinv64};
use glam::Vec2;

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ReconstructionFilter {
    /// Box of radius 0.5 pixel.
    Box,
    /// Tent (triangle) of the given radius in pixels (Mitsuba default 1).
    Tent { radius: f32 },
    /// Gaussian with the given standard deviation, truncated at 4σ (Mitsuba: σ = 0.5, radius 2).
    Gaussian { stddev: f32 },
}

impl ReconstructionFilter {
    pub fn from_props(props: &Props) -> Result<ReconstructionFilter, SceneError> {
        match props.plugin_type.as_str() {
            "box" => {
                props.expect_only(&[], &[])?;
                Ok(ReconstructionFilter::Box)
            }
            "tent" => {
                props.expect_only(&["radius"], &[])?;
                let radius = props.float("radius", 1.0)?;
                if !(radius > 0.0 && radius.is_finite()) {
                    return Err(props.error_at("radius", "tent radius must be positive"));
                }
                Ok(ReconstructionFilter::Tent { radius })
            }
            "gaussian" => {
                props.expect_only(&["stddev"], &[])?;
                let stddev = props.float("stddev", 0.5)?;
                if !(stddev > 0.0 && stddev.is_finite()) {
                    return Err(props.error_at("stddev", "gaussian stddev must be positive"));
                }
                Ok(ReconstructionFilter::Gaussian { stddev })
            }
            other => Err(props.error(format!(
                "unsupported reconstruction filter '{other}' (supported: box, tent, gaussian)"
            ))),
        }
    }

    /// Filter support radius in pixels.
    pub fn radius(&self) -> f32 {
        match *self {
            ReconstructionFilter::Box => 0.5,
            ReconstructionFilter::Tent { radius } => radius,
            ReconstructionFilter::Gaussian { stddev } => 4.0 * stddev,
        }
    }

    /// The 1D filter profile at offset `x` from the pixel centre, up to a constant factor (zero outside
    /// the support). Splatting divides by its integral over the image, so the scale cancels.
    pub fn eval_1d(&self, x: f32) -> f32 {
        let r = self.radius();
        if !(x.abs() <= r) {
            return 0.0;
        }
        match *self {
            ReconstructionFilter::Box => 1.0,
            ReconstructionFilter::Tent { radius } => (radius - x.abs()).max(0.0),
            ReconstructionFilter::Gaussian { stddev } => (-0.5 * (x / stddev) * (x / stddev)).exp(),
        }
    }

    /// Samples an offset from the pixel centre, distributed as the (separable) filter.
    pub fn sample(&self, u: Vec2) -> Vec2 {
        Vec2::new(self.sample_1d(u.x), self.sample_1d(u.y))
    }

    fn sample_1d(&self, u: f32) -> f32 {
        match *self {
            ReconstructionFilter::Box => u - 0.5,
            ReconstructionFilter::Tent { radius } => {
                // Inverse CDF of the triangle on [-r, r].
                if u < 0.5 {
                    radius * ((2.0 * u).sqrt() - 1.0)
                } else {
                    radius * (1.0 - (2.0 - 2.0 * u).sqrt())
                }
            }
            ReconstructionFilter::Gaussian { stddev } => {
                // Truncated normal on [-4σ, 4σ] through the inverse error function of the rescaled CDF.
                let r = 4.0 * stddev as f64;
                let s = stddev as f64 * std::f64::consts::SQRT_2;
                let lo = erf64(-r / s);
                let hi = erf64(r / s);
                let x = s * erfinv64(lo + (hi - lo) * u as f64);
                x.clamp(-r, r) as f32
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Histogram of sampled offsets against the analytic filter shape.
    fn check_shape(filter: ReconstructionFilter, shape: impl Fn(f32) -> f32) {
        let n = 200_000;
        let bins = 40;
        let r = filter.radius();
        let mut hist = vec![0usize; bins];
        for i in 0..n {
            let u = (i as f32 + 0.5) / n as f32;
            let x = filter.sample_1d(u);
            assert!(x.abs() <= r + 1e-5, "{x} outside radius {r}");
            let b = (((x + r) / (2.0 * r)) * bins as f32).floor().clamp(0.0, bins as f32 - 1.0) as usize;
            hist[b] += 1;
        }
        let w = 2.0 * r / bins as f32;
        let norm: f32 =
            (0..1000).map(|i| shape(-r + (i as f32 + 0.5) * 2.0 * r / 1000.0)).sum::<f32>() * 2.0 * r
                / 1000.0;
        for (b, &count) in hist.iter().enumerate() {
            let c = -r + (b as f32 + 0.5) * w;
            let expected = shape(c) / norm * w;
            let got = count as f32 / n as f32;
            assert!((got - expected).abs() < 2e-3, "bin {b}: got {got}, expected {expected}");
        }
    }

    #[test]
    fn tent_samples_follow_the_triangle() {
        check_shape(ReconstructionFilter::Tent { radius: 1.0 }, |x| (1.0 - x.abs()).max(0.0));
    }

    #[test]
    fn gaussian_samples_follow_the_bell() {
        check_shape(ReconstructionFilter::Gaussian { stddev: 0.5 }, |x| (-x * x / (2.0 * 0.25)).exp());
    }
}
