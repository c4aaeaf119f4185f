//! Special functions the samplers need (std has no erf): the error function, its complement and its
//! inverse, in f64. Beckmann visible-normal sampling and the Gaussian pixel filter both invert the
//! same erf they evaluate, so sampling and density agree.

use std::f64::consts::PI as PI64;

/// Complementary error function with relative error below 1.2e-7 everywhere (Chebyshev fit,
/// Numerical Recipes §6.2), evaluated in f64.
pub fn erfc64(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806
                        + t * (0.27886807
                            + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

pub fn erf64(x: f64) -> f64 {
    if x == f64::INFINITY {
        return 1.0;
    }
    1.0 - erfc64(x)
}

/// Inverse error function: Giles' single-precision approximation (2010) polished by a Newton
/// step on [`erf64`], so the sampling routines invert the same erf they evaluate.
pub fn erfinv64(y: f64) -> f64 {
    if y <= -1.0 {
        return -6.0;
    }
    if y >= 1.0 {
        return 6.0;
    }
    let mut w = -((1.0 - y) * (1.0 + y)).ln();
    let p = if w < 5.0 {
        w -= 2.5;
        let mut p = 2.810_226_36e-08;
        for c in [
            3.432_739_39e-07,
            -3.523_387_7e-06,
            -4.391_506_54e-06,
            0.000_218_580_87,
            -0.001_253_725_03,
            -0.004_177_681_64,
            0.246_640_727,
            1.501_409_41,
        ] {
            p = c + p * w;
        }
        p
    } else {
        w = w.sqrt() - 3.0;
        let mut p = -0.000_200_214_257;
        for c in [
            0.000_100_950_558,
            0.001_349_343_22,
            -0.003_673_428_44,
            0.005_739_507_73,
            -0.007_622_461_3,
            0.009_438_870_47,
            1.001_674_06,
            2.832_976_82,
        ] {
            p = c + p * w;
        }
        p
    };
    let mut x = p * y;
    let d = 2.0 / PI64.sqrt() * (-x * x).exp();
    if d > 1e-300 {
        x -= (erf64(x) - y) / d;
    }
    x.clamp(-6.0, 6.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erf_matches_reference_values_and_inverts() {
        for (x, e) in [(0.5, 0.520_499_877_8), (1.0, 0.842_700_792_9), (2.0, 0.995_322_265)] {
            assert!((erf64(x) - e).abs() < 2e-7, "erf({x})");
            assert!((erf64(-x) + e).abs() < 2e-7);
        }
        for y in [-0.999, -0.5, 0.0, 0.3, 0.9, 0.99999] {
            assert!((erf64(erfinv64(y)) - y).abs() < 1e-9, "erfinv({y})");
        }
    }
}
