//! Renders split over machines and sittings (issue 31): `render --part K/N` and `hslt merge`,
//! `--checkpoint` and `--resume`, and SIGTERM/SIGINT writing the state so far. Pixel integrators must
//! merge and resume to exactly the single render; Metropolis ones to an image that agrees with the
//! reference as well as one render of the same work does.

use hslt::image::{read_exr_metadata, read_image, ImageBuf};
use hslt::report::metrics;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;

fn hslt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hslt"))
}

fn cornell() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml").display().to_string()
}

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hslt-farm-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(args: &[&str]) -> Output {
    let out = hslt().args(args).output().unwrap();
    assert!(out.status.success(), "hslt {args:?} failed: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A BDPT render of the 32×32 Cornell box at 1024 spp, made once for the tests that need it.
fn bdpt_reference() -> PathBuf {
    static REFERENCE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    REFERENCE
        .get_or_init(|| {
            let reference = tmp_dir("reference").join("reference.exr");
            render(&reference, &["--integrator", "bdpt", "--spp", "1024", "--seed", "99"]);
            reference
        })
        .clone()
}

fn rel_mse(img: &Path, reference: &Path) -> f64 {
    let (a, b) = (read_image(img, false).unwrap(), read_image(reference, false).unwrap());
    metrics::compute(&a, &b, 1e-2).unwrap().rel_mse
}

fn mean(img: &ImageBuf) -> f64 {
    img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64
}

fn meta(p: &Path, key: &str) -> Option<String> {
    read_exr_metadata(p).unwrap().into_iter().find(|(k, _)| k == key).map(|(_, v)| v)
}

/// Renders the Cornell box at 32×32 with `extra` options to `out`.
fn render(out: &Path, extra: &[&str]) -> Output {
    let scene = cornell();
    let mut args = vec!["render", &scene, "-D", "resx=32", "-D", "resy=32", "-q", "-o", path(out)];
    args.extend_from_slice(extra);
    run(&args)
}

#[test]
fn pt_parts_merge_to_exactly_the_single_render_and_any_subset_is_unbiased() {
    let dir = tmp_dir("pt-parts");
    let single = dir.join("single.exr");
    render(&single, &["--spp", "24", "--seed", "7"]);
    let parts: Vec<PathBuf> = (1..=3).map(|k| dir.join(format!("part{k}.exr"))).collect();
    for (k, p) in parts.iter().enumerate() {
        render(p, &["--spp", "24", "--seed", "7", "--part", &format!("{}/3", k + 1)]);
        assert_eq!(meta(p, "hslt.spp").as_deref(), Some("8"), "part {} has its third of 24 spp", k + 1);
    }
    let merged = dir.join("merged.exr");
    run(&["merge", path(&parts[2]), path(&parts[0]), path(&parts[1]), "-o", path(&merged), "-q"]);
    let err = rel_mse(&merged, &single);
    assert!(err <= 1e-6, "merged parts against the single render: rel MSE {err:e}");
    assert_eq!(meta(&merged, "hslt.spp").as_deref(), Some("24"));

    // Parts 1 and 2 of 24 spp hold sample indices 0..16: the single render of 16 spp.
    let first_two = dir.join("first_two.exr");
    let sixteen = dir.join("sixteen.exr");
    render(&sixteen, &["--spp", "16", "--seed", "7"]);
    run(&["merge", path(&parts[0]), path(&parts[1]), "-o", path(&first_two), "-q"]);
    let err = rel_mse(&first_two, &sixteen);
    assert!(err <= 1e-6, "parts 1+2 against the 16-spp render: rel MSE {err:e}");

    // Parts 1 and 3 are no single render, but an unbiased one of 16 spp: as close to the 24-spp
    // image as the 16-spp render is, and of the same brightness.
    let outer = dir.join("outer.exr");
    let out = run(&["merge", path(&parts[0]), path(&parts[2]), "-o", path(&outer)]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing 2"), "the merge names the missing part");
    let (outer_err, sixteen_err) = (rel_mse(&outer, &single), rel_mse(&sixteen, &single));
    assert!(
        outer_err < 2.0 * sixteen_err,
        "parts 1+3: rel MSE {outer_err:e} against 16 spp's {sixteen_err:e}"
    );
    // Each part is an unbiased render of its own; the merge is their mean weighted by samples.
    let (p1, p3) = (read_image(&parts[0], false).unwrap(), read_image(&parts[2], false).unwrap());
    let outer_img = read_image(&outer, false).unwrap();
    for ((&o, &x), &y) in outer_img.data.iter().zip(&p1.data).zip(&p3.data) {
        let expected = 0.5 * (x as f64 + y as f64);
        assert!((o as f64 - expected).abs() <= 1e-6 * expected.abs().max(1e-3), "{o} against {expected}");
    }
}

/// Renders `--part 1/2` and `2/2` with `options` into `dir` and merges them; returns part 1 and the merge.
fn two_parts_merged(dir: &Path, options: &[&str]) -> (PathBuf, PathBuf) {
    let (a, b, merged) = (dir.join("a.exr"), dir.join("b.exr"), dir.join("merged.exr"));
    for (part, out) in [("1/2", &a), ("2/2", &b)] {
        let mut args = options.to_vec();
        args.extend(["--part", part]);
        render(out, &args);
    }
    run(&["merge", path(&a), path(&b), "-o", path(&merged), "-q"]);
    (a, merged)
}

#[test]
fn bdpt_parts_with_light_tracing_splats_merge_exactly() {
    let dir = tmp_dir("bdpt-parts");
    let single = dir.join("single.exr");
    let options = ["--integrator", "bdpt", "--spp", "8", "--seed", "3"];
    render(&single, &options);
    let (_, merged) = two_parts_merged(&dir, &options);
    let err = rel_mse(&merged, &single);
    assert!(err <= 1e-6, "bdpt merged parts against the single render: rel MSE {err:e}");
}

#[test]
fn merge_refuses_parts_of_different_renders_and_a_part_twice() {
    let dir = tmp_dir("refuse");
    let (a, b, c, plain) = (dir.join("a.exr"), dir.join("b.exr"), dir.join("c.exr"), dir.join("plain.exr"));
    render(&a, &["--spp", "4", "--part", "1/2"]);
    render(&b, &["--spp", "4", "--part", "2/2", "--integrator", "bdpt"]);
    render(&c, &["--spp", "4", "--part", "2/2", "--seed", "5"]);
    render(&plain, &["--spp", "4"]);
    let out_path = dir.join("out.exr");
    let out = path(&out_path);
    let cases: [(&[&str], &[&str]); 4] = [
        (&["merge", path(&a), path(&b), "-o", out], &["not parts of one render", "hslt.integrator"]),
        (&["merge", path(&a), path(&c), "-o", out], &["not parts of one render", "hslt.seed"]),
        (&["merge", path(&a), path(&a), "-o", out], &["part 1/2 is in both"]),
        (&["merge", path(&a), path(&plain), "-o", out], &["plain.exr", "hslt.part.count"]),
    ];
    for (args, needles) in cases {
        let o = hslt().args(args).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && !err.contains("panicked"), "{args:?}: {err}");
        for n in needles {
            assert!(err.contains(n), "{args:?}: '{n}' missing from: {err}");
        }
    }
    assert!(!out_path.exists(), "a refused merge wrote its output");
    let o = hslt().args(["render", &cornell(), "--spp", "2", "--part", "1/3", "-o", out]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot be split into 3 parts"));
}

#[test]
fn pssmlt_parts_merge_as_well_as_one_render_of_their_work() {
    let dir = tmp_dir("pssmlt-parts");
    let reference = bdpt_reference();
    let single = dir.join("single.exr");
    let options = ["--integrator", "pssmlt", "--spp", "128", "--seed", "2"];
    render(&single, &options);
    let (a, merged) = two_parts_merged(&dir, &options);
    assert_eq!(
        meta(&merged, "hslt.state.mutations"),
        meta(&single, "hslt.samples"),
        "the parts split the mutations"
    );
    let (e_part, e_merged, e_single) =
        (rel_mse(&a, &reference), rel_mse(&merged, &reference), rel_mse(&single, &reference));
    assert!(e_merged < 0.8 * e_part, "merging halved nothing: part {e_part:e}, merged {e_merged:e}");
    assert!(e_merged < 1.5 * e_single, "merged {e_merged:e} against one render's {e_single:e}");
    let (m, r) = (mean(&read_image(&merged, false).unwrap()), mean(&read_image(&reference, false).unwrap()));
    assert!((m / r - 1.0).abs() < 0.02, "merged mean {m} against the reference's {r}");
}

/// The arguments of a 32×32 Cornell box render with `extra` options, checkpointed every `every`
/// seconds to `checkpoint`, written to `out`.
fn checkpointed(extra: &[&str], checkpoint: &Path, every: &str, out: &Path) -> Vec<String> {
    let mut args: Vec<String> =
        ["render", &cornell(), "-D", "resx=32", "-D", "resy=32", "-q"].map(String::from).to_vec();
    args.extend(extra.iter().map(|a| a.to_string()));
    for a in ["--checkpoint", path(checkpoint), "--checkpoint-every", every, "-o", path(out)] {
        args.push(a.to_string());
    }
    args
}

/// Starts a render, waits until its checkpoint exists, then sends `signal`.
fn interrupt_after_checkpoint(args: &[String], checkpoint: &Path, signal: &str) -> Output {
    let child = hslt().args(args).stderr(std::process::Stdio::piped()).spawn().unwrap();
    let start = std::time::Instant::now();
    while !checkpoint.exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "no checkpoint after 60 s");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(300));
    let status = Command::new("kill").args([signal, &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    child.wait_with_output().unwrap()
}

#[cfg(unix)]
#[test]
fn pt_stopped_by_sigterm_and_resumed_equals_the_uninterrupted_render() {
    let dir = tmp_dir("pt-resume");
    let full = dir.join("full.exr");
    render(&full, &["--spp", "1500", "--seed", "11", "--threads", "1"]);
    let (first, checkpoint, resumed) =
        (dir.join("first.exr"), dir.join("state.exr"), dir.join("resumed.exr"));
    let args = checkpointed(&["--spp", "1500", "--seed", "11", "--threads", "1"], &checkpoint, "0.5", &first);
    let out = interrupt_after_checkpoint(&args, &checkpoint, "-TERM");
    assert_eq!(out.status.code(), Some(130), "SIGTERM ends the render as interrupted");
    assert_eq!(meta(&checkpoint, "hslt.checkpoint.complete").as_deref(), Some("false"));
    let done: u32 = meta(&checkpoint, "hslt.spp").unwrap().parse().unwrap();
    assert!(done > 0 && done < 1500, "the checkpoint holds {done} of 1500 spp");
    assert_eq!(meta(&first, "hslt.spp"), meta(&checkpoint, "hslt.spp"), "the output holds the image so far");

    // Options other than outputs and run settings come from the checkpoint.
    let o = hslt()
        .args(["render", "--resume", path(&checkpoint), "--spp", "4", "-o", path(&resumed)])
        .output()
        .unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--spp"));
    let o = hslt()
        .args(["render", "--resume", path(&checkpoint), "--chains", "4", "-o", path(&resumed)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("takes the render's options from"), "{err}");
    run(&["render", "--resume", path(&checkpoint), "-o", path(&resumed), "-q"]);
    assert_eq!(meta(&resumed, "hslt.spp").as_deref(), Some("1500"));
    let err = rel_mse(&resumed, &full);
    assert!(err <= 1e-10, "resumed against uninterrupted: rel MSE {err:e}");
    assert_eq!(meta(&checkpoint, "hslt.checkpoint.complete").as_deref(), Some("true"));
    // Resuming a complete render again only writes its outputs (a requeued farm task).
    let again_path = dir.join("again.exr");
    let again = run(&["render", "--resume", path(&checkpoint), "-o", path(&again_path)]);
    assert!(String::from_utf8_lossy(&again.stderr).contains("nothing left to render"));
    assert!(rel_mse(&again_path, &full) <= 1e-10);
}

#[cfg(unix)]
#[test]
fn hslt_mlt_stopped_by_sigint_and_resumed_agrees_with_the_reference() {
    let dir = tmp_dir("hslt-resume");
    let reference = bdpt_reference();
    let whole = dir.join("whole.exr");
    render(&whole, &["--integrator", "hslt+mlt", "--time", "4", "--seed", "1"]);
    let (first, checkpoint, resumed) =
        (dir.join("first.exr"), dir.join("state.exr"), dir.join("resumed.exr"));
    let args =
        checkpointed(&["--integrator", "hslt+mlt", "--time", "4", "--seed", "1"], &checkpoint, "1", &first);
    let out = interrupt_after_checkpoint(&args, &checkpoint, "-INT");
    assert_eq!(out.status.code(), Some(130));
    run(&["render", "--resume", path(&checkpoint), "-o", path(&resumed), "-q"]);
    let elapsed: f64 = meta(&resumed, "hslt.elapsed_seconds").unwrap().parse().unwrap();
    assert!((3.5..6.0).contains(&elapsed), "the two runs took {elapsed} s of the 4 asked for");
    assert_eq!(meta(&resumed, "hslt.resumed_segments").as_deref(), Some("2"));
    let (e_resumed, e_whole, e_first) =
        (rel_mse(&resumed, &reference), rel_mse(&whole, &reference), rel_mse(&first, &reference));
    assert!(e_resumed < 2.0 * e_whole, "resumed {e_resumed:e} against uninterrupted {e_whole:e}");
    assert!(e_resumed < e_first, "the resumed run added nothing: {e_resumed:e} against {e_first:e}");
    let (m, r) = (mean(&read_image(&resumed, false).unwrap()), mean(&read_image(&reference, false).unwrap()));
    assert!((m / r - 1.0).abs() < 0.02, "resumed mean {m} against the reference's {r}");
}

#[test]
fn resume_refuses_a_changed_scene_file_or_mesh() {
    let dir = tmp_dir("changed");
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/jewelry");
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    for file in ["scene.xml", "meshes/gem.obj", "meshes/ring.obj"] {
        std::fs::copy(source.join(file), dir.join(file)).unwrap();
    }
    let (scene, checkpoint, first) = (dir.join("scene.xml"), dir.join("state.exr"), dir.join("a.exr"));
    let resume = || {
        let o =
            hslt().args(["render", "--resume", path(&checkpoint), "-o", path(&dir.join("b.exr"))]).output();
        let o = o.unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let start = [
        "render",
        path(&scene),
        "-D",
        "resx=16",
        "-D",
        "resy=12",
        "--spp",
        "2",
        "-q",
        "--checkpoint",
        path(&checkpoint),
        "-o",
        path(&first),
    ];
    run(&start);
    assert!(resume().0, "an unchanged scene resumes");

    // A mesh the scene loads: one more comment line changes no geometry but is another file.
    let mesh = dir.join("meshes/gem.obj");
    let text = std::fs::read_to_string(&mesh).unwrap();
    std::fs::write(&mesh, format!("{text}# edited\n")).unwrap();
    let (ok, err) = resume();
    assert!(!ok && err.contains("has changed"), "resumed with a changed mesh: {err}");

    std::fs::write(&mesh, &text).unwrap();
    let xml = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(&scene, xml.replace("</scene>", "<!-- edited -->\n</scene>")).unwrap();
    let (ok, err) = resume();
    assert!(!ok && err.contains("has changed"), "resumed a changed scene file: {err}");
}
