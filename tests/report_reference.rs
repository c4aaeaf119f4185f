//! `hslt reference`: a render continued with `--resume` is the same image as one straight render of
//! all its samples (pixel streams continue at the stored sample count), the EXR carries what resuming
//! needs, and resuming something else fails with a clear error naming the file.

use hslt::image::{read_exr_metadata, read_image};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hslt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hslt"))
}

fn cornell() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml").display().to_string()
}

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hslt-report-ref-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(args: &[&str]) -> Output {
    let out = hslt().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    out
}

fn run_ok(args: &[&str]) {
    let out = run(args);
    assert!(out.status.success(), "{args:?} failed: {}", String::from_utf8_lossy(&out.stderr));
}

fn run_err(args: &[&str], needles: &[&str]) {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    for n in needles {
        assert!(err.contains(n), "{args:?}: '{n}' missing from: {err}");
    }
}

fn meta(path: &Path, key: &str) -> String {
    let m = read_exr_metadata(path).unwrap();
    m.iter().find(|(k, _)| k == key).unwrap_or_else(|| panic!("no {key} in {}", path.display())).1.clone()
}

const SMALL: [&str; 4] = ["-D", "resx=32", "-D", "resy=24"];

#[test]
fn resumed_render_equals_a_straight_render_of_all_samples() {
    let dir = tmp_dir("resume");
    let scene = cornell();
    let resumed = dir.join("resumed.exr");
    let straight = dir.join("straight.exr");
    let r = resumed.to_str().unwrap();
    let base = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = ["reference", &scene, "-q", "-o", r].iter().map(|s| s.to_string()).collect();
        v.extend(SMALL.iter().map(|s| s.to_string()));
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let args = base(&["--integrator", "pt", "--spp", "3", "--seed", "7"]);
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(meta(&resumed, "hslt.spp"), "3");
    assert_eq!(meta(&resumed, "hslt.integrator"), "pt");
    assert_eq!(meta(&resumed, "hslt.seed"), "7");
    let args = base(&["--resume", "--spp", "5"]);
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(meta(&resumed, "hslt.spp"), "8");
    assert_eq!(meta(&resumed, "hslt.reference.segments"), "2");
    assert_eq!(meta(&resumed, "hslt.reference.complete"), "true");

    let mut args =
        vec!["render", &scene, "-q", "--spp", "8", "--seed", "7", "-o", straight.to_str().unwrap()];
    args.extend(SMALL);
    run_ok(&args);
    let (a, b) = (read_image(&resumed, false).unwrap(), read_image(&straight, false).unwrap());
    assert_eq!((a.width, a.height), (b.width, b.height));
    let mut worst = 0.0f32;
    for (x, y) in a.data.iter().zip(&b.data) {
        worst = worst.max((x - y).abs() / (1e-3 + y.abs()));
    }
    // Same samples, summed in another order and through one f32 rounding of the checkpoint.
    assert!(worst < 1e-5, "resumed and straight renders differ by {worst} (relative)");
    // And not trivially: the first 3 spp alone are a different (noisier) image.
    assert!(a.data.iter().any(|&v| v > 0.0));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn checkpoints_during_a_timed_render_leave_a_complete_reference() {
    let dir = tmp_dir("checkpoints");
    let out = dir.join("ref.exr");
    let scene = cornell();
    // A checkpoint every 0.12 s during 0.6 s: the writer thread runs several times.
    let mut args = vec![
        "reference",
        &scene,
        "-q",
        "-o",
        out.to_str().unwrap(),
        "--time",
        "0.6",
        "--checkpoint-minutes",
        "0.002",
    ];
    args.extend(SMALL);
    run_ok(&args);
    assert_eq!(meta(&out, "hslt.reference.complete"), "true");
    assert_eq!(meta(&out, "hslt.seed"), "1000003", "reference's own default seed");
    assert!(meta(&out, "hslt.spp").parse::<u32>().unwrap() >= 1);
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "temporary files left behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn resuming_needs_a_matching_checkpoint() {
    let dir = tmp_dir("bad-resume");
    let scene = cornell();
    let out = dir.join("ref.exr");
    let o = out.to_str().unwrap();
    let with_small = |v: &[&str]| -> Vec<String> {
        v.iter().chain(SMALL.iter()).map(|s| s.to_string()).collect::<Vec<_>>()
    };
    let call = |v: Vec<String>, needles: &[&str]| {
        run_err(&v.iter().map(String::as_str).collect::<Vec<_>>(), needles)
    };
    call(
        with_small(&["reference", &scene, "-q", "-o", o, "--resume", "--spp", "1"]),
        &["ref.exr", "does not exist"],
    );
    call(with_small(&["reference", &scene, "-q", "-o", "ref.png", "--spp", "1"]), &["ref.png", ".exr"]);
    run_ok(
        &with_small(&["reference", &scene, "-q", "-o", o, "--spp", "1", "--seed", "3"])
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    call(
        with_small(&["reference", &scene, "-q", "-o", o, "--resume", "--spp", "1", "--seed", "4"]),
        &["ref.exr", "seed 3"],
    );
    // Another film size than the checkpoint's.
    call(
        vec!["reference", &scene, "-q", "-o", o, "--resume", "--spp", "1", "-D", "resx=16", "-D", "resy=16"]
            .into_iter()
            .map(String::from)
            .collect(),
        &["ref.exr", "32x24", "16x16"],
    );
    // An EXR that no `hslt reference` wrote.
    let foreign = dir.join("foreign.exr");
    hslt::image::write_image(&foreign, &hslt::image::ImageBuf::new(32, 24, 3), &Vec::new()).unwrap();
    call(
        with_small(&["reference", &scene, "-q", "-o", foreign.to_str().unwrap(), "--resume", "--spp", "1"]),
        &["foreign.exr", "hslt.integrator"],
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
