//! Integration tests of image I/O: EXR (exr crate) round trips with metadata and layers, PNG/TIFF/HDR
//! and JPEG through OpenImageIO (or the png crate without the `oiio` feature), atomic writes and
//! the public test scenes' reference renders and textures.

mod common;

use std::path::{Path, PathBuf};

use hslt::image::{
    linear_to_srgb, oiio_version, read_exr_layers, read_exr_metadata, read_image, srgb_to_linear,
    write_exr_layers, write_image, write_image_with_report, ImageBuf, Metadata, NON_FINITE_KEY,
};

/// A fresh directory under the system temp dir, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("hslt-image-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn entries(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Deterministic image whose values span many magnitudes (exercises exact float storage).
fn test_image(width: usize, height: usize, channels: usize, salt: u32) -> ImageBuf {
    let mut img = ImageBuf::new(width, height, channels);
    let mut state = 0x9e37_79b9u32 ^ salt;
    for v in &mut img.data {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let unit = (state >> 8) as f32 / (1u32 << 24) as f32;
        let exponent = (state % 17) as i32 - 8;
        *v = unit * 2f32.powi(exponent);
    }
    img
}

fn meta(pairs: &[(&str, &str)]) -> Metadata {
    pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
}

#[test]
fn exr_round_trip_is_exact_and_keeps_metadata() {
    let dir = TempDir::new("exr-rt");
    let path = dir.path("render.exr");
    let img = test_image(37, 23, 3, 1);
    let written = meta(&[
        ("seed", "12345"),
        ("integrator", "hslt"),
        ("spp", "256"),
        ("software", "hslt 0.1"),
        ("comments", "naïve UTF-8 ✓"),
    ]);
    write_image(&path, &img, &written).unwrap();
    let back = read_image(&path, true).unwrap();
    assert_eq!(back, img, "float32 EXR must round-trip bit-exactly");

    let mut expected = written.clone();
    expected.sort();
    assert_eq!(read_exr_metadata(&path).unwrap(), expected);
    assert_eq!(dir.entries(), vec!["render.exr".to_string()]);
}

#[test]
fn exr_round_trip_grey_and_rgba_layouts() {
    let dir = TempDir::new("exr-layouts");
    for channels in [1, 2, 4] {
        let path = dir.path(&format!("c{channels}.exr"));
        let img = test_image(8, 5, channels, channels as u32);
        write_image(&path, &img, &Metadata::new()).unwrap();
        assert_eq!(read_image(&path, false).unwrap(), img, "{channels} channels");
    }
}

#[test]
fn multi_layer_exr_round_trip() {
    let dir = TempDir::new("exr-layers");
    let path = dir.path("strategies.exr");
    let main = test_image(16, 9, 3, 10);
    let s2t1 = test_image(16, 9, 3, 11);
    let s1t2 = test_image(16, 9, 3, 12);
    let written = meta(&[("integrator", "bdpt"), ("spp", "64")]);
    let layers = [("main", &main), ("strategy.s2t1", &s2t1), ("strategy.s1t2", &s1t2)];
    let report = write_exr_layers(&path, &layers, &written).unwrap();
    assert_eq!(report.non_finite_replaced, 0);

    let back = read_exr_layers(&path).unwrap();
    let names: Vec<&str> = back.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["main", "strategy.s2t1", "strategy.s1t2"]);
    for ((_, expected), (_, got)) in layers.iter().zip(&back) {
        assert_eq!(*expected, got);
    }
    // The plain reader returns the first layer, i.e. the main image.
    assert_eq!(read_image(&path, false).unwrap(), main);
    assert_eq!(read_exr_metadata(&path).unwrap(), meta(&[("integrator", "bdpt"), ("spp", "64")]));
}

#[test]
fn multi_layer_exr_rejects_bad_layers_without_leaving_files() {
    let dir = TempDir::new("exr-bad-layers");
    let path = dir.path("bad.exr");
    let a = test_image(4, 4, 3, 1);
    let small = test_image(2, 4, 3, 2);
    let cases: [&[(&str, &ImageBuf)]; 4] = [
        &[("main", &a), ("main", &a)],
        &[("", &a), ("strategy.s0t2", &a)],
        &[("main", &a), ("strategy.s0t2", &small)],
        &[],
    ];
    for layers in cases {
        let err = write_exr_layers(&path, layers, &Metadata::new()).unwrap_err();
        assert!(format!("{err:#}").contains("bad.exr"), "{err:#}");
    }
    assert!(dir.entries().is_empty(), "left behind: {:?}", dir.entries());
}

#[test]
fn reserved_or_duplicate_exr_metadata_is_refused() {
    let dir = TempDir::new("exr-meta");
    let img = test_image(4, 4, 3, 3);
    for bad in [meta(&[("channels", "x")]), meta(&[("spp", "1"), ("spp", "2")]), meta(&[("", "x")])] {
        let err = write_image(&dir.path("m.exr"), &img, &bad).unwrap_err();
        assert!(format!("{err:#}").contains("m.exr"), "{err:#}");
    }
    assert!(dir.entries().is_empty());
}

#[test]
fn non_finite_values_are_zeroed_counted_and_recorded() {
    let dir = TempDir::new("nonfinite");
    let path = dir.path("nan.exr");
    let mut img = test_image(5, 5, 3, 4);
    img.data[0] = f32::NAN;
    img.data[7] = f32::INFINITY;
    img.data[20] = f32::NEG_INFINITY;
    let report = write_image_with_report(&path, &img, &meta(&[("seed", "1")])).unwrap();
    assert_eq!(report.non_finite_replaced, 3);
    let back = read_image(&path, false).unwrap();
    assert_eq!(back.count_non_finite(), 0);
    for (i, (&a, &b)) in img.data.iter().zip(&back.data).enumerate() {
        if a.is_finite() {
            assert_eq!(a, b, "value {i}");
        } else {
            assert_eq!(b, 0.0, "value {i}");
        }
    }
    let recorded = read_exr_metadata(&path).unwrap();
    assert!(recorded.contains(&(NON_FINITE_KEY.to_string(), "3".to_string())), "{recorded:?}");
}

#[test]
fn png_round_trip_within_srgb_quantisation() {
    let dir = TempDir::new("png");
    let path = dir.path("ramp.png");
    let mut img = ImageBuf::new(64, 4, 3);
    for y in 0..4 {
        for x in 0..64 {
            let t = x as f32 / 63.0;
            img.pixel_mut(x, y).copy_from_slice(&[t, t * t, 1.0 - t]);
        }
    }
    img.pixel_mut(0, 0)[0] = 3.0; // over-range must clamp to white
    write_image(&path, &img, &meta(&[("integrator", "pt")])).unwrap();

    let linear = read_image(&path, true).unwrap();
    assert_eq!((linear.width, linear.height, linear.channels), (64, 4, 3));
    for (i, (&orig, &got)) in img.data.iter().zip(&linear.data).enumerate() {
        let encoded_error = (linear_to_srgb(orig.clamp(0.0, 1.0)) - linear_to_srgb(got)).abs();
        assert!(encoded_error <= 0.5 / 255.0 + 1e-5, "value {i}: wrote {orig}, read {got}");
    }

    // Undecoded values are exactly the 8-bit codes of our own tonemap.
    let raw = read_image(&path, false).unwrap();
    let codes: Vec<u8> = raw.data.iter().map(|v| (v * 255.0).round() as u8).collect();
    assert_eq!(codes, img.to_srgb8());
    assert!(raw.data.iter().all(|v| (v * 255.0 - (v * 255.0).round()).abs() < 1e-3));
}

#[test]
fn png_with_alpha_keeps_alpha_linear() {
    let dir = TempDir::new("png-alpha");
    let path = dir.path("alpha.png");
    let mut img = ImageBuf::new(3, 1, 4);
    img.data = vec![0.5, 0.5, 0.5, 0.25, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
    write_image(&path, &img, &Metadata::new()).unwrap();
    let back = read_image(&path, true).unwrap();
    assert_eq!(back.channels, 4);
    assert!((back.data[3] - 64.0 / 255.0).abs() < 1e-6, "alpha {}", back.data[3]);
    assert!((back.data[0] - srgb_to_linear(188.0 / 255.0)).abs() < 1e-6, "colour {}", back.data[0]);
}

#[test]
fn atomic_write_replaces_target_and_leaves_no_temp_file() {
    let dir = TempDir::new("atomic");
    let path = dir.path("out.exr");
    let first = test_image(6, 6, 3, 5);
    let second = test_image(6, 6, 3, 6);
    write_image(&path, &first, &Metadata::new()).unwrap();
    write_image(&path, &second, &Metadata::new()).unwrap();
    assert_eq!(read_image(&path, false).unwrap(), second);
    assert_eq!(dir.entries(), vec!["out.exr".to_string()]);

    // A failing write (duplicate metadata) must leave the previous image intact and no temp file.
    let bad = meta(&[("k", "1"), ("k", "2")]);
    assert!(write_image(&path, &first, &bad).is_err());
    assert_eq!(read_image(&path, false).unwrap(), second);
    assert_eq!(dir.entries(), vec!["out.exr".to_string()]);
}

#[test]
fn failed_writes_name_the_file_and_leave_nothing() {
    let dir = TempDir::new("failed");
    let img = test_image(4, 4, 3, 7);

    let missing = dir.path("no/such/dir/out.exr");
    let err = format!("{:#}", write_image(&missing, &img, &Metadata::new()).unwrap_err());
    assert!(err.contains("no/such/dir/out.exr"), "{err}");

    let unknown = dir.path("out.xyz");
    let err = format!("{:#}", write_image(&unknown, &img, &Metadata::new()).unwrap_err());
    assert!(err.contains("out.xyz") && err.contains(".png") && err.contains(".exr"), "{err}");

    let mut broken = img.clone();
    broken.data.pop();
    let err = format!("{:#}", write_image(&dir.path("short.png"), &broken, &Metadata::new()).unwrap_err());
    assert!(err.contains("short.png"), "{err}");

    assert!(dir.entries().is_empty(), "left behind: {:?}", dir.entries());
}

#[test]
fn reading_bad_files_gives_errors_naming_them() {
    let dir = TempDir::new("bad-read");
    let missing = dir.path("absent.exr");
    assert!(format!("{:#}", read_image(&missing, true).unwrap_err()).contains("absent.exr"));
    for name in ["garbage.exr", "garbage.png"] {
        let path = dir.path(name);
        std::fs::write(&path, b"this is not an image at all").unwrap();
        let err = format!("{:#}", read_image(&path, true).unwrap_err());
        assert!(err.contains(name), "{err}");
    }
    let err = format!("{:#}", read_exr_metadata(&dir.path("garbage.png")).unwrap_err());
    assert!(err.contains("garbage.png"), "{err}");
}

#[test]
fn tungsten_reference_exrs_read_as_plausible_images() {
    let scenes = common::shared_scenes();
    let mut checked = 0;
    for scene in ["cornell-box", "veach-ajar", "veach-bidir", "veach-mis"] {
        let path = scenes.join(scene).join("TungstenRender.exr");
        let img = read_image(&path, true).unwrap();
        assert!(img.width >= 64 && img.height >= 64, "{scene}: {}x{}", img.width, img.height);
        assert!(img.channels == 3 || img.channels == 4, "{scene}: {} channels", img.channels);
        assert_eq!(img.count_non_finite(), 0, "{scene}");
        let colour: Vec<f32> = img.data.chunks(img.channels).flat_map(|p| p[..3].iter().copied()).collect();
        let mean = colour.iter().map(|&v| f64::from(v)).sum::<f64>() / colour.len() as f64;
        assert!(mean > 1e-3 && mean < 50.0, "{scene}: implausible mean {mean}");
        assert!(colour.iter().all(|&v| v >= 0.0), "{scene}: negative radiance");
        checked += 1;
    }
    assert_eq!(checked, 4);
}

#[cfg(feature = "oiio")]
mod with_oiio {
    use super::*;

    fn assert_same_dims(path: &Path, a: &ImageBuf, b: &ImageBuf) {
        assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels), "{}", path.display());
    }

    #[test]
    fn version_is_reported() {
        let version = oiio_version().expect("built with oiio");
        let major: u32 = version.split('.').next().unwrap().parse().unwrap();
        assert!(major >= 2, "{version}");
    }

    #[test]
    fn veach_ajar_jpeg_textures_read_and_linearise() {
        let scenes = common::shared_scenes();
        let dir = scenes.join("veach-ajar/textures");
        let mut count = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if extension_is(&path, "jpg") {
                let linear = read_image(&path, true).unwrap();
                let raw = read_image(&path, false).unwrap();
                assert_same_dims(&path, &linear, &raw);
                assert!(linear.width > 0 && linear.height > 0);
                assert_eq!(linear.channels, 3, "{}", path.display());
                assert!(linear.data.iter().all(|&v| (0.0..=1.0).contains(&v)), "{}", path.display());
                // Decoding sRGB darkens every mid-tone, so the linear mean must be below the raw one.
                let mean = |img: &ImageBuf| {
                    img.data.iter().map(|&v| f64::from(v)).sum::<f64>() / img.data.len() as f64
                };
                assert!(mean(&linear) < mean(&raw), "{}", path.display());
                for (&l, &r) in linear.data.iter().zip(&raw.data).step_by(997) {
                    assert!((l - srgb_to_linear(r)).abs() < 1e-6);
                }
                count += 1;
            }
        }
        assert!(count >= 3, "expected the three JPEG textures, found {count}");
    }

    fn extension_is(path: &Path, ext: &str) -> bool {
        path.extension().is_some_and(|e| e.eq_ignore_ascii_case(ext))
    }

    #[test]
    fn concurrent_reads_agree() {
        let scenes = common::shared_scenes();
        let path = scenes.join("veach-ajar/textures/cherry-wood-texture.jpg");
        let reference = read_image(&path, true).unwrap();
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..4).map(|_| s.spawn(|| read_image(&path, true).unwrap())).collect();
            for h in handles {
                assert_eq!(h.join().unwrap(), reference);
            }
        });
    }

    #[test]
    fn tiff_is_float_exact_and_hdr_is_close() {
        let dir = TempDir::new("tiff-hdr");
        let img = test_image(12, 7, 3, 8);
        let tiff = dir.path("out.tiff");
        write_image(&tiff, &img, &meta(&[("seed", "9")])).unwrap();
        assert_eq!(read_image(&tiff, true).unwrap(), img, "TIFF stores linear float32");

        let hdr = dir.path("out.hdr");
        write_image(&hdr, &img, &Metadata::new()).unwrap();
        let back = read_image(&hdr, true).unwrap();
        assert_same_dims(&hdr, &back, &img);
        for (pixel_in, pixel_out) in img.data.chunks(3).zip(back.data.chunks(3)) {
            // RGBE keeps 8 mantissa bits relative to the pixel's largest component.
            let scale = pixel_in.iter().cloned().fold(0.0f32, f32::max);
            for (a, b) in pixel_in.iter().zip(pixel_out) {
                assert!((a - b).abs() <= scale / 128.0 + 1e-6, "{a} vs {b}");
            }
        }
        assert_eq!(dir.entries(), vec!["out.hdr".to_string(), "out.tiff".to_string()]);
    }

    #[test]
    fn jpeg_output_drops_alpha_and_reads_back() {
        let dir = TempDir::new("jpeg");
        let path = dir.path("out.jpg");
        let mut img = ImageBuf::new(16, 16, 4);
        for p in img.data.chunks_mut(4) {
            p.copy_from_slice(&[0.2, 0.2, 0.2, 0.5]);
        }
        write_image(&path, &img, &Metadata::new()).unwrap();
        let back = read_image(&path, true).unwrap();
        assert_eq!((back.width, back.height, back.channels), (16, 16, 3));
        // JPEG is lossy, but a flat grey block survives to within a couple of 8-bit codes.
        for &v in &back.data {
            assert!((linear_to_srgb(v) - linear_to_srgb(0.2)).abs() < 3.0 / 255.0, "{v}");
        }
    }
}

#[cfg(not(feature = "oiio"))]
mod without_oiio {
    use super::*;

    #[test]
    fn no_version_and_clear_errors_for_oiio_formats() {
        assert_eq!(oiio_version(), None);
        let dir = TempDir::new("no-oiio");
        let img = test_image(4, 4, 3, 9);
        for name in ["a.jpg", "a.tiff", "a.hdr"] {
            let err = format!("{:#}", write_image(&dir.path(name), &img, &Metadata::new()).unwrap_err());
            assert!(err.contains(name) && err.contains("oiio"), "{err}");
        }
        assert!(dir.entries().is_empty(), "left behind: {:?}", dir.entries());
        let err = format!("{:#}", read_image(Path::new("tex.jpg"), true).unwrap_err());
        assert!(err.contains("tex.jpg") && err.contains("oiio"), "{err}");
    }
}

#[test]
fn exr_reader_accepts_half_and_prefixed_channels() {
    use exr::prelude::*;
    let dir = TempDir::new("exr-half");
    let path = dir.path("half.exr");
    let (w, h) = (5usize, 3usize);
    let value = |x: usize, y: usize, c: usize| (x + 10 * y) as f32 * 0.1 + c as f32;
    // Half-float channels under a "diffuse." prefix plus an unrelated float channel "Z".
    let plane =
        |c: usize| FlatSamples::F16((0..w * h).map(|p| f16::from_f32(value(p % w, p / w, c))).collect());
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("diffuse.R", plane(0)),
        AnyChannel::new("diffuse.G", plane(1)),
        AnyChannel::new("diffuse.B", plane(2)),
        AnyChannel::new("Z", FlatSamples::F32(vec![7.0; w * h])),
    ]));
    Image::from_channels((w, h), channels).write().to_file(&path).unwrap();

    let img = read_image(&path, true).unwrap();
    assert_eq!((img.width, img.height, img.channels), (w, h, 3));
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let expected = f16::from_f32(value(x, y, c)).to_f32();
                assert_eq!(img.pixel(x, y)[c], expected, "({x},{y}) channel {c}");
            }
        }
    }
}
