//! `hslt error` on tiny Cornell-box renders: an image against itself has zero error, fewer samples
//! give more error, two references are averaged and their own noise printed, the table carries each
//! image's metadata, and a size mismatch is refused naming the file.

use std::path::{Path, PathBuf};
use std::process::Command;

fn hslt(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_hslt")).args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    out
}

fn render(dir: &Path, name: &str, spp: &str, seed: &str, res: (&str, &str)) -> String {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = dir.join(name).display().to_string();
    let (rx, ry) = (format!("resx={}", res.0), format!("resy={}", res.1));
    let args = [
        "render",
        scene.to_str().unwrap(),
        "-D",
        &rx,
        "-D",
        &ry,
        "--integrator",
        "pt",
        "--spp",
        spp,
        "--seed",
        seed,
        "--threads",
        "1",
        "-o",
        &out,
    ];
    let status = hslt(&args);
    assert!(status.status.success(), "render failed: {}", String::from_utf8_lossy(&status.stderr));
    out
}

/// The rows of the Markdown table: (image, integrator, seed, spp, rel MSE, block rel MSE, worst-1% share).
fn rows(stdout: &str) -> Vec<(String, String, String, String, f64, f64, f64)> {
    stdout
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| image"))
        .map(|l| {
            let f: Vec<&str> = l.trim_matches('|').split('|').map(str::trim).collect();
            (
                f[0].to_string(),
                f[1].to_string(),
                f[2].to_string(),
                f[3].to_string(),
                f[4].parse().unwrap(),
                f[5].parse().unwrap(),
                f[6].parse().unwrap(),
            )
        })
        .collect()
}

#[test]
fn error_ranks_sample_counts_and_reports_the_references_own_noise() {
    let dir: PathBuf = std::env::temp_dir().join(format!("hslt-report-error-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let res = ("16", "12");
    let ref_a = render(&dir, "ref-a.exr", "512", "101", res);
    let ref_b = render(&dir, "ref-b.exr", "512", "102", res);
    let few = render(&dir, "few.exr", "4", "1", res);
    let many = render(&dir, "many.exr", "64", "2", res);

    let out = hslt(&["error", &few, &many, &ref_a, "--reference", &ref_a, "--reference", &ref_b]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let table = rows(&stdout);
    assert_eq!(table.len(), 3, "{stdout}");
    let (few_row, many_row, ref_row) = (&table[0], &table[1], &table[2]);
    assert_eq!((few_row.1.as_str(), few_row.2.as_str(), few_row.3.as_str()), ("pt", "1", "4"), "{stdout}");
    assert_eq!(many_row.3, "64");
    // 16× the samples: about 16× less error; a factor 4 leaves room for the references' own noise.
    assert!(few_row.4 > 4.0 * many_row.4, "4 spp {} against 64 spp {}", few_row.4, many_row.4);
    assert!(few_row.5 < few_row.4, "block means average noise away: {} ≥ {}", few_row.5, few_row.4);
    // 192 pixels, so the worst 1% is two of them: at least their even share, well below all of it.
    assert!((2.0 / 192.0..0.9).contains(&few_row.6), "worst-1% share {}", few_row.6);
    // One of the two references against their mean: a quarter of their mutual error (up to the
    // relative MSE's denominators, the mean's square against the other reference's).
    let noise_line = stdout.lines().find(|l| l.starts_with("reference: mean of")).expect("noise line");
    let mutual: f64 =
        noise_line.split("relative MSE ").nth(1).unwrap().split(',').next().unwrap().parse().unwrap();
    assert!(
        (ref_row.4 - mutual / 4.0).abs() < 0.25 * mutual,
        "a reference against the mean {} should be a quarter of {mutual}",
        ref_row.4
    );

    let same = hslt(&["error", &few, "--reference", &few]);
    let same_rows = rows(&String::from_utf8_lossy(&same.stdout));
    assert_eq!((same_rows[0].4, same_rows[0].5, same_rows[0].6), (0.0, 0.0, 0.0));

    let other_size = render(&dir, "small.exr", "4", "1", ("8", "6"));
    let bad = hslt(&["error", &other_size, "--reference", &ref_a]);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("small.exr") && err.contains("8x6") && err.contains("16x12"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
