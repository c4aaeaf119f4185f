//! Resource exhaustion turned into errors (#33): inputs that nest deeply, declare huge counts or lie
//! in their headers end with one error naming the file and exit status 1 under an 8 GiB address-space
//! cap (`ulimit -v`), never an abort or an out-of-memory kill; and `--max-memory` refuses what would
//! not fit while loading and stops a render that grows past it, keeping the image so far.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const EIGHT_GIB_IN_KIB: u64 = 8 << 20;

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hslt-limits-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `hslt ARGS` under `ulimit -v 8 GiB` (through the shell, so no unsafe pre-exec hook is needed).
fn hslt_capped(args: &[&str]) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {EIGHT_GIB_IN_KIB} && exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_hslt"))
        .args(args)
        .output()
        .unwrap()
}

/// Exit status 1 (not a signal, not a panic's 101), exactly one `error:` line, holding every needle.
fn assert_one_error(out: &Output, what: &str, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{what}: status {:?}; stderr: {err}", out.status);
    assert!(!err.contains("panicked") && !err.contains("memory allocation"), "{what}: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{what}: expected one error line: {err}");
    for n in needles {
        assert!(lines[0].contains(n), "{what}: '{n}' missing from: {}", lines[0]);
    }
}

const SCENE_HEAD: &str = r#"<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 30" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <emitter type="constant"/>
"#;

fn scene_with(body: &str) -> String {
    format!("{SCENE_HEAD}{body}</scene>\n")
}

#[test]
fn lying_and_runaway_inputs_are_one_error_under_an_8_gib_address_space_cap() {
    let dir = tmp_dir("cap");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut cases: Vec<(&str, PathBuf, Vec<String>)> = Vec::new();

    let deep = dir.join("deep.xml");
    let n = 200_000;
    std::fs::write(&deep, format!("<scene>{}{}</scene>", "<bsdf>".repeat(n), "</bsdf>".repeat(n))).unwrap();
    cases.push(("nesting 200 000 deep", deep, vec!["deep.xml:1:".into(), "nested more than".into()]));

    // A PLY header declaring four billion vertices in a file of a few hundred bytes.
    let ply = dir.join("huge-count.ply");
    std::fs::write(
        &ply,
        "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n\
         property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n\
         end_header\n0000000000000000",
    )
    .unwrap();
    let ply_scene = dir.join("ply.xml");
    std::fs::write(
        &ply_scene,
        scene_with(r#"<shape type="ply"><string name="filename" value="huge-count.ply"/></shape>"#),
    )
    .unwrap();
    cases.push(("a PLY declaring 4e9 vertices", ply_scene, vec!["huge-count.ply".into()]));

    // A film of 65536² pixels (about 150 GiB of buffers).
    let film = dir.join("film.xml");
    std::fs::write(
        &film,
        scene_with("")
            .replace(r#"name="width" value="8""#, r#"name="width" value="65536""#)
            .replace(r#"name="height" value="8""#, r#"name="height" value="65536""#),
    )
    .unwrap();
    cases.push(("a 65536² film", film, vec!["film.xml:".into(), "<film".into(), "film needs".into()]));

    // Textures whose headers claim far more pixels than their files hold: a PNG (read through
    // OpenImageIO) and an EXR found by fuzzing (read by the exr crate).
    for (name, texture) in [
        ("png.xml", root.join("tests/data/cli/huge-header.png")),
        ("exr.xml", root.join("fuzz/regressions/exr/exr-00.exr")),
    ] {
        let scene = dir.join(name);
        let body = format!(
            r#"<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
               <string name="filename" value="{}"/></texture></bsdf></shape>"#,
            texture.display()
        );
        std::fs::write(&scene, scene_with(&body)).unwrap();
        let file_name = texture.file_name().unwrap().to_str().unwrap().to_string();
        cases.push(("a texture with a lying header", scene, vec![file_name]));
    }

    for (what, scene, needles) in &cases {
        let out = dir.join("out.exr");
        let args = ["render", scene.to_str().unwrap(), "--spp", "1", "-q", "-o", out.to_str().unwrap()];
        let needles: Vec<&str> = needles.iter().map(String::as_str).collect();
        assert_one_error(&hslt_capped(&args), what, &needles);
        assert!(!out.exists(), "{what}: an output was written");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Many shapes, each fine alone: the loader keeps count of what the ray-query build will need and
/// stops at the shape where it no longer fits (here 2000 spheres of 16 000 triangles each, about
/// 4 GiB of build, under a 1 GiB cap; without the check the build would take it all and more).
#[test]
fn a_scene_of_too_many_shapes_is_refused_at_the_shape_where_memory_runs_out() {
    let dir = tmp_dir("count");
    let scene = dir.join("spheres.xml");
    let spheres: String = (0..2000)
        .map(|i| {
            format!("<shape type=\"sphere\"><point name=\"center\" x=\"{i}\" y=\"0\" z=\"0\"/></shape>\n")
        })
        .collect();
    std::fs::write(&scene, scene_with(&spheres)).unwrap();
    let out = dir.join("out.exr");
    let args = ["render", scene.to_str().unwrap(), "--max-memory", "1G", "-q", "-o", out.to_str().unwrap()];
    let result = hslt_capped(&args);
    assert_one_error(
        &result,
        "2000 spheres under 1 GiB",
        &["spheres.xml:", "<shape type=\"sphere\">", "triangles needs", "--max-memory"],
    );
    // Refused part-way, not at the first shape nor after the last: the error is on a line between.
    let err = String::from_utf8_lossy(&result.stderr);
    let line: usize = err.split("spheres.xml:").nth(1).unwrap().split(':').next().unwrap().parse().unwrap();
    assert!(line > 20 && line < 2000, "refused at line {line}: {err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A render whose memory grows past `--max-memory` (here BDPT's per-strategy layers, about 700 MiB
/// at 512², under a 400 MiB cap) stops within the watch's polling, writes what it has, and exits 1.
#[test]
fn max_memory_stops_a_growing_render_and_keeps_the_image_so_far() {
    let dir = tmp_dir("grow");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = dir.join("strategies.exr");
    let args = [
        "render",
        scene.to_str().unwrap(),
        "-D",
        "resx=512",
        "-D",
        "resy=512",
        "--integrator",
        "bdpt",
        "--bdpt-strategies",
        "8",
        "--spp",
        "100000",
        "--max-memory",
        "400M",
        "-q",
        "-o",
        out.to_str().unwrap(),
    ];
    let start = Instant::now();
    let result = hslt_capped(&args);
    // 100 000 spp would take hours: stopping is what ended it.
    assert!(start.elapsed() < Duration::from_secs(120), "took {:?}", start.elapsed());
    assert_one_error(
        &result,
        "a growing render",
        &["resident memory reached", "--max-memory 400 MiB", "strategies.exr"],
    );
    let meta = hslt::image::read_exr_metadata(&out).expect("the image so far was written");
    let get = |k: &str| meta.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    assert_eq!(get("hslt.interrupted").as_deref(), Some("true"));
    // Without the cap the same command starts rendering (checked at 1 spp, so it ends).
    let mut uncapped: Vec<&str> = args.to_vec();
    let spp = uncapped.iter().position(|a| *a == "100000").unwrap();
    uncapped[spp] = "1";
    uncapped.retain(|a| *a != "--max-memory" && *a != "400M");
    let ok = hslt_capped(&uncapped);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn max_memory_refuses_at_load_what_would_not_fit_and_rejects_bad_sizes() {
    let dir = tmp_dir("load");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = dir.join("x.exr");
    let base = ["render", scene.to_str().unwrap(), "-q", "-o", out.to_str().unwrap(), "--spp", "1"];
    let film = [&base[..], &["-D", "resx=8000", "-D", "resy=8000", "--max-memory", "512M"]].concat();
    assert_one_error(
        &hslt_capped(&film),
        "an 8000² film under 512 MiB",
        &["scene.xml:", "<film", "--max-memory leaves"],
    );
    let bad = [&base[..], &["--max-memory", "lots"]].concat();
    let result = hslt_capped(&bad);
    assert_eq!(result.status.code(), Some(2), "a usage error");
    assert!(String::from_utf8_lossy(&result.stderr).contains("not a size such as 4G"));
    let _ = std::fs::remove_dir_all(&dir);
}
