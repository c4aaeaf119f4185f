//! `hslt compare` on a 32×24 Cornell box for a couple of seconds per integrator: every report file is
//! written, the CSV has one monotone time series per integrator, the error falls from the first
//! snapshot to the last, and a reference of the wrong size is refused with a clear error.

use hslt::registry::IntegratorKind;
use std::path::{Path, PathBuf};
use std::process::Command;

fn hslt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hslt"))
}

fn cornell() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml").display().to_string()
}

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hslt-report-compare-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(args: &[&str]) -> std::process::Output {
    let out = hslt().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    out
}

const SMALL: [&str; 4] = ["-D", "resx=32", "-D", "resy=24"];

/// The integrators to compare: the path tracer, plus BDPT once this build has it.
fn integrators() -> Vec<&'static str> {
    let mut names = vec!["pt"];
    if IntegratorKind::parse("bdpt").is_ok() {
        names.push("bdpt");
    }
    names
}

struct Row {
    integrator: String,
    seconds: f64,
    samples: u64,
    rel_mse: f64,
    rmse: f64,
    mae: f64,
}

fn parse_csv(text: &str) -> Vec<Row> {
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("integrator,elapsed_seconds,samples,spp,rel_mse,rmse,mae,acceptance_rate"),
        "CSV header"
    );
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 8, "CSV line {l:?}");
            Row {
                integrator: f[0].to_string(),
                seconds: f[1].parse().unwrap(),
                samples: f[2].parse().unwrap(),
                rel_mse: f[4].parse().unwrap(),
                rmse: f[5].parse().unwrap(),
                mae: f[6].parse().unwrap(),
            }
        })
        .collect()
}

#[test]
fn compare_writes_the_report_and_error_falls_with_time() {
    let dir = tmp_dir("cornell");
    let scene = cornell();
    let reference = dir.join("ref.exr");
    let mut args = vec![
        "reference",
        &scene,
        "-q",
        "--integrator",
        "pt",
        "--spp",
        "2048",
        "-o",
        reference.to_str().unwrap(),
    ];
    args.extend(SMALL);
    let out = run(&args);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    let report = dir.join("report");
    let names = integrators();
    let list = names.join(",");
    let mut args = vec![
        "compare",
        &scene,
        "-q",
        "--reference",
        reference.to_str().unwrap(),
        "--integrators",
        &list,
        "--time",
        "1.5",
        "--snapshots",
        "6",
        "--out",
        report.to_str().unwrap(),
    ];
    args.extend(SMALL);
    let out = run(&args);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    for f in ["error.csv", "error.svg", "error.png", "index.html", "reference.png", "reference-crop0.png"] {
        assert!(report.join(f).is_file(), "{f} missing");
    }
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    let svg = std::fs::read_to_string(report.join("error.svg")).unwrap();
    let rows = parse_csv(&std::fs::read_to_string(report.join("error.csv")).unwrap());
    for name in &names {
        for f in [
            format!("{name}.exr"),
            format!("{name}.png"),
            format!("{name}-error.png"),
            format!("{name}-crop0.png"),
        ] {
            assert!(report.join(&f).is_file(), "{f} missing");
            assert!(f.ends_with(".exr") || html.contains(&format!("src=\"{f}\"")), "{f} not on the page");
        }
        let legend = svg.split("<text").any(|t| {
            t.split_once('>').is_some_and(|(_, body)| body.trim_start().starts_with(&format!("{name}\n")))
        });
        assert!(legend, "{name} has no legend entry in the plot");
        let exr = hslt::image::read_image(&report.join(format!("{name}.exr")), false).unwrap();
        assert_eq!((exr.width, exr.height), (32, 24));

        let series: Vec<&Row> = rows.iter().filter(|r| &r.integrator == name).collect();
        assert!(series.len() >= 4, "{name}: only {} snapshots", series.len());
        for w in series.windows(2) {
            assert!(
                w[1].seconds > w[0].seconds,
                "{name}: times not increasing: {} then {}",
                w[0].seconds,
                w[1].seconds
            );
            assert!(w[1].samples >= w[0].samples, "{name}: samples went down");
        }
        let (first, last) = (series[0], series[series.len() - 1]);
        assert!((last.seconds - 1.5).abs() < 0.5, "{name}: ran {} s of 1.5", last.seconds);
        assert!(first.seconds < 0.2, "{name}: first snapshot only at {} s", first.seconds);
        for r in &series {
            assert!(r.rel_mse.is_finite() && r.rmse > 0.0 && r.mae > 0.0, "{name}: bad metrics");
        }
        // Many times more samples at the end: the error must have come down clearly.
        assert!(
            last.rel_mse < 0.7 * first.rel_mse && last.rmse < first.rmse,
            "{name}: error did not fall: relMSE {} -> {}, RMSE {} -> {}",
            first.rel_mse,
            last.rel_mse,
            first.rmse,
            last.rmse
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn compare_refuses_bad_arguments_before_rendering() {
    let dir = tmp_dir("bad");
    let scene = cornell();
    let reference = dir.join("small.exr");
    hslt::image::write_image(&reference, &hslt::image::ImageBuf::new(16, 16, 3), &Vec::new()).unwrap();
    let out_dir = dir.join("out");
    let base = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<&str> = vec![
            "compare",
            &scene,
            "-q",
            "--reference",
            reference.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ];
        v.extend(SMALL);
        v.extend(extra);
        v.into_iter().map(String::from).collect()
    };
    let cases: [(&[&str], &[&str]); 5] = [
        (&["--integrators", "pt", "--time", "1", "--min-depth", "0"], &["--min-depth"]),
        (&["--integrators", "pt", "--time", "1"], &["small.exr", "16x16", "32x24"]),
        (&["--integrators", "pt,nonsense", "--time", "1"], &["nonsense"]),
        (&["--integrators", "pt,pt", "--time", "1"], &["twice"]),
        (&["--integrators", "pt", "--time", "-1"], &["--time"]),
    ];
    for (extra, needles) in cases {
        let args = base(extra);
        let out = run(&args.iter().map(String::as_str).collect::<Vec<_>>());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{extra:?} succeeded");
        for n in needles {
            assert!(err.contains(n), "{extra:?}: '{n}' missing from: {err}");
        }
    }
    assert!(!out_dir.join("error.csv").exists(), "a refused comparison wrote a report");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn compare_from_a_min_depth_warns_when_the_reference_holds_other_light() {
    let dir = tmp_dir("min-depth");
    let scene = cornell();
    let reference = dir.join("indirect.exr");
    let mut args = vec!["render", &scene, "-q", "--integrator", "pt", "--spp", "8", "--min-depth", "3"];
    args.extend(SMALL);
    args.extend(["-o", reference.to_str().unwrap()]);
    assert!(run(&args).status.success());
    let compare = |min_depth: &str, out: &Path| {
        let mut args = vec!["compare", &scene, "-q", "--integrators", "pt", "--time", "0.3"];
        args.extend(SMALL);
        args.extend(["--seed", "5", "--snapshots", "2", "--min-depth", min_depth]);
        args.extend(["--reference", reference.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let out = run(&args);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let same = dir.join("same");
    let err = compare("3", &same);
    assert!(!err.contains("--min-depth"), "{err}");
    let meta = hslt::image::read_exr_metadata(&same.join("pt.exr")).unwrap();
    assert!(meta.iter().any(|(k, v)| k == "hslt.min_depth" && v == "3"), "{meta:?}");
    let err = compare("1", &dir.join("other"));
    assert!(err.contains("warning") && err.contains("--min-depth 3"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
