//! The report's error metrics on synthetic images whose errors are known in closed form.

use hslt::image::ImageBuf;
use hslt::report::metrics::{compute, relative_error_map, Metric, DEFAULT_REL_EPSILON};

fn image(w: usize, h: usize, f: impl Fn(usize, usize, usize) -> f32) -> ImageBuf {
    let mut img = ImageBuf::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                img.pixel_mut(x, y)[c] = f(x, y, c);
            }
        }
    }
    img
}

#[test]
fn constant_offset_gives_known_values() {
    // Reference 1 everywhere, image 1.5: every value is off by 0.5.
    let r = image(8, 4, |_, _, _| 1.0);
    let x = image(8, 4, |_, _, _| 1.5);
    let m = compute(&x, &r, DEFAULT_REL_EPSILON).unwrap();
    assert!((m.rel_mse - 0.25 / 1.01).abs() < 1e-9, "{}", m.rel_mse);
    assert!((m.rmse - 0.5).abs() < 1e-9);
    assert!((m.mae - 0.5).abs() < 1e-9);
}

#[test]
fn relative_mse_weighs_dark_and_bright_regions_alike() {
    // Left half dark (0.1), right half bright (10), both off by 10%: each pixel's relative error is
    // 0.01 r² / (r² + ε), while RMSE is dominated by the bright half.
    let r = image(4, 2, |x, _, _| if x < 2 { 0.1 } else { 10.0 });
    let x = image(4, 2, |x, _, _| if x < 2 { 0.11 } else { 11.0 });
    let eps = 1e-4;
    let m = compute(&x, &r, eps).unwrap();
    let dark = 1e-4 / (0.01 + eps);
    let bright = 1.0 / (100.0 + eps);
    assert!((m.rel_mse - (dark + bright) / 2.0).abs() < 1e-6, "{}", m.rel_mse);
    assert!((m.rmse - ((1e-4 + 1.0) / 2.0f64).sqrt()).abs() < 1e-5, "{}", m.rmse);
    assert!((m.mae - (0.01 + 1.0) / 2.0).abs() < 1e-5, "{}", m.mae);
}

#[test]
fn epsilon_keeps_black_reference_pixels_finite() {
    let r = image(2, 2, |_, _, _| 0.0);
    let x = image(2, 2, |x, y, _| if (x, y) == (0, 0) { 0.2 } else { 0.0 });
    let m = compute(&x, &r, 1e-2).unwrap();
    // One pixel of four with 0.04 / 0.01 = 4 in every channel.
    assert!((m.rel_mse - 1.0).abs() < 1e-6, "{}", m.rel_mse);
    let map = relative_error_map(&x, &r, 1e-2).unwrap();
    assert!((map[0] - 4.0).abs() < 1e-6 && map[1..].iter().all(|&v| v == 0.0), "{map:?}");
}

#[test]
fn alpha_is_ignored_and_channels_are_averaged() {
    let r = image(1, 1, |_, _, _| 1.0);
    let mut x = ImageBuf::new(1, 1, 4);
    x.data.copy_from_slice(&[1.0, 1.0, 4.0, 0.0]);
    let m = compute(&x, &r, 0.0).unwrap();
    // Only the blue channel differs, by 3: mean of (0, 0, 9).
    assert!((m.rel_mse - 3.0).abs() < 1e-9);
    assert!((m.mae - 1.0).abs() < 1e-9);
}

#[test]
fn metric_names_parse_and_unknown_ones_are_listed() {
    assert_eq!(Metric::parse("relmse"), Ok(Metric::RelMse));
    assert_eq!(Metric::parse("rmse"), Ok(Metric::Rmse));
    let err = Metric::parse("psnr").unwrap_err();
    assert!(err.contains("psnr") && err.contains("relmse"), "{err}");
}
