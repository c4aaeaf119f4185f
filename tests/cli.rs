//! The `hslt` command as a user meets it: bad input gives one clear error line and a non-zero exit
//! (never a panic), warnings for recoverable problems, Ctrl-C writes the image rendered so far,
//! and outputs carry their metadata.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hslt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hslt"))
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cli").join(name)
}

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hslt-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Runs `hslt info` on a scene and expects a failure whose single error line contains `needles`.
fn expect_error(args: &[&str], needles: &[&str]) {
    let out = hslt().args(args).output().unwrap();
    let err = stderr(&out);
    assert!(!out.status.success(), "{args:?} succeeded; stderr: {err}");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    let error_lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(error_lines.len(), 1, "{args:?}: expected one error line, got: {err}");
    for n in needles {
        assert!(error_lines[0].contains(n), "{args:?}: '{n}' missing from: {}", error_lines[0]);
    }
}

#[test]
fn malformed_xml_names_file_and_line() {
    let f = data("malformed.xml");
    expect_error(&["info", f.to_str().unwrap()], &["malformed.xml:"]);
}

#[test]
fn unknown_plugin_is_named() {
    let f = data("unknown-plugin.xml");
    expect_error(&["info", f.to_str().unwrap()], &["unknown-plugin.xml:6", "velvet-unicorn"]);
}

#[test]
fn missing_mesh_names_the_path() {
    let f = data("base.xml");
    expect_error(&["info", f.to_str().unwrap(), "-D", "mesh=does-not-exist.obj"], &["does-not-exist.obj"]);
}

#[test]
fn truncated_ply_is_an_error() {
    let f = data("base.xml");
    let out = hslt().args(["info", f.to_str().unwrap(), "-D", "mesh=truncated.ply"]).output().unwrap();
    let err = stderr(&out);
    assert!(!out.status.success() && !err.contains("panicked"), "{err}");
    assert!(err.contains("truncated.ply"), "{err}");
}

#[test]
fn nan_vertex_is_an_error() {
    let f = data("base.xml");
    expect_error(&["info", f.to_str().unwrap(), "-D", "mesh=nan.obj"], &["nan.obj"]);
}

#[test]
fn degenerate_triangle_is_skipped_with_a_warning() {
    let f = data("base.xml");
    let out = hslt().args(["info", f.to_str().unwrap(), "-D", "mesh=degenerate.obj"]).output().unwrap();
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    assert!(err.lines().any(|l| l.starts_with("warning:") && l.contains("degenerate")), "{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("triangles  1"));
}

#[test]
fn undefined_parameter_and_bad_cli_values_are_errors() {
    let f = data("base.xml");
    expect_error(&["render", f.to_str().unwrap(), "-o", "x.exr", "--integrator", "nope"], &["nope"]);
    expect_error(&["render", f.to_str().unwrap(), "-o", "x.bmp"], &["x.bmp"]);
    expect_error(&["info", data("nope.xml").to_str().unwrap()], &["nope.xml"]);
    let f = f.to_str().unwrap();
    expect_error(
        &["render", f, "-o", "x.exr", "--integrator", "bdpt", "--direct-samples", "4"],
        &["Metropolis"],
    );
    expect_error(
        &["render", f, "-o", "x.exr", "--integrator", "pssmlt", "--direct-share", "0.2"],
        &["--time"],
    );
    expect_error(
        &["render", f, "-o", "x.exr", "--integrator", "pssmlt", "--time", "1", "--direct-share", "1.5"],
        &["--direct-share"],
    );
    expect_error(&["render", f, "-o", "x.exr", "--min-depth", "0"], &["--min-depth"]);
    expect_error(
        &["render", f, "-o", "x.exr", "--min-depth", "3", "--max-depth", "2"],
        &["--min-depth", "(2)"],
    );
}

#[test]
fn info_reports_what_the_scene_needs() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = hslt().args(["info", scene.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("texture system: no"), "{text}");
    assert!(text.contains("manifold walk (specular/glossy vertices): no"), "{text}");
    assert!(text.contains("lights     1 (area)"), "{text}");
}

#[test]
fn render_writes_exr_with_metadata_and_png() {
    let dir = tmp_dir("render");
    let exr = dir.join("out.exr");
    let png = dir.join("out.png");
    let f = data("base.xml");
    let out = hslt()
        .args(["render", f.to_str().unwrap(), "-o", exr.to_str().unwrap(), "-o", png.to_str().unwrap()])
        .args(["--spp", "4", "--seed", "9", "-q"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(png.metadata().unwrap().len() > 0);
    let meta = hslt::image::read_exr_metadata(&exr).unwrap();
    let get = |k: &str| meta.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    assert_eq!(get("hslt.seed").as_deref(), Some("9"));
    assert_eq!(get("hslt.integrator").as_deref(), Some("pt"));
    assert_eq!(get("hslt.spp").as_deref(), Some("4"));
    let leftovers: Vec<_> =
        std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
    assert_eq!(leftovers.len(), 2, "temporary files left behind: {leftovers:?}");
}

#[cfg(unix)]
#[test]
fn interrupt_writes_the_image_so_far() {
    let dir = tmp_dir("interrupt");
    let exr = dir.join("partial.exr");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let child = hslt()
        .args(["render", scene.to_str().unwrap(), "-o", exr.to_str().unwrap(), "--time", "60", "-q"])
        .args(["--threads", "1"])
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(2500));
    let status = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "expected the interrupted exit code");
    let img = hslt::image::read_image(&exr, false).unwrap();
    let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len() as f64;
    assert!(img.data.iter().all(|v| v.is_finite()) && mean > 0.01, "partial image mean {mean}");
    let meta = hslt::image::read_exr_metadata(&exr).unwrap();
    assert!(meta.iter().any(|(k, v)| k == "hslt.interrupted" && v == "true"));
}

#[test]
fn bench_rays_compares_both_backends() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = hslt()
        .args(["bench", "rays", scene.to_str().unwrap(), "--rays", "4000", "--large", "0", "--threads", "1"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in ["embree", "bvh", "primary", "diffuse", "shadow", "corrector", "Mrays/s"] {
        assert!(text.contains(needle), "'{needle}' missing from:\n{text}");
    }
}

/// `bench pt` against a stand-in for a Python that imports Mitsuba: it answers the probe with a
/// version and every render with fixed timings, and records the arguments it was given, so the test
/// sees what reaches Mitsuba and that the printed ratio is computed from both sides' times.
#[test]
fn bench_pt_times_our_process_against_mitsuba_side_by_side() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tmp_dir("bench-mitsuba");
    let (python, calls) = (dir.join("python"), dir.join("calls.txt"));
    let stub = format!(
        "#!/bin/sh\n\
         if [ $# -eq 2 ]; then echo 3.9.1; exit 0; fi\n\
         shift 2\n\
         echo \"$@\" >> {calls}\n\
         echo '{{\"version\": \"3.9.1\", \"import_seconds\": 0.5, \"load_seconds\": 0.25, \
         \"first_render_seconds\": 120.0, \"render_seconds\": 100.0, \"samples\": 512, \
         \"peak_memory_bytes\": 1073741824}}'\n",
        calls = calls.display()
    );
    std::fs::write(&python, stub).unwrap();
    std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = hslt()
        .args(["bench", "pt", scene.to_str().unwrap(), "-D", "resx=16", "-D", "resy=16", "--spp", "2"])
        .args(["--threads", "1", "--repeats", "2", "--mitsuba-variants", "llvm_ad_rgb"])
        .arg("--mitsuba-python")
        .arg(&python)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    // Two pairs: our process twice, the stand-in twice, with the scene, spp, threads and -D values.
    let recorded = std::fs::read_to_string(&calls).unwrap();
    let lines: Vec<&str> = recorded.lines().collect();
    assert_eq!(lines.len(), 2, "{recorded}");
    for needle in ["llvm_ad_rgb", "scene.xml", " 2 1 ", "\"resx\":\"16\"", "\"resy\":\"16\""] {
        assert!(lines[0].contains(needle), "'{needle}' missing from Mitsuba's arguments: {}", lines[0]);
    }
    let ours = text.lines().find(|l| l.starts_with("hslt pt, whole process")).expect(&text);
    let our_secs: f64 = ours.split_whitespace().nth(4).unwrap().parse().unwrap();
    assert!(our_secs > 0.0 && our_secs < 60.0, "{ours}");
    assert!(text.contains("mitsuba llvm_ad_rgb, render alone"), "{text}");
    let ratio_line = text.lines().find(|l| l.contains("ratio:")).expect(&text);
    let ratio: f64 = ratio_line.split(" is ").nth(1).unwrap().split('x').next().unwrap().parse().unwrap();
    // Stand-in's 100 s over our time, which is printed rounded to two decimals.
    let (low, high) = (100.0 / (our_secs + 0.005), 100.0 / (our_secs - 0.005));
    assert!((low - 0.01..=high + 0.01).contains(&ratio), "{ratio_line} with our {our_secs} s");
    assert!(ratio_line.contains("peak memory"), "{ratio_line}");
}

#[test]
fn bench_pt_skips_mitsuba_with_the_reason_when_it_cannot_be_imported() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let out = hslt()
        .args(["bench", "pt", scene.to_str().unwrap(), "-D", "resx=16", "-D", "resy=16", "--spp", "1"])
        .args(["--threads", "1", "--mitsuba-python", "/bin/false"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("samples/s"), "{text}");
    for variant in ["llvm_ad_rgb", "scalar_rgb"] {
        let line = text.lines().find(|l| l.contains(variant)).expect(&text);
        assert!(line.contains("skipped") && line.contains("cannot import Mitsuba 3"), "{line}");
    }
    assert!(!text.contains("side by side"), "{text}");
}

#[test]
fn hslt_direction_reaches_the_mutation_and_the_metadata() {
    let dir = tmp_dir("direction");
    let exr = dir.join("out.exr");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/jewelry/scene.xml");
    let out = hslt()
        .args([
            "render",
            scene.to_str().unwrap(),
            "-o",
            exr.to_str().unwrap(),
            "-D",
            "resx=32",
            "-D",
            "resy=24",
        ])
        .args(["--integrator", "hslt", "--hslt-direction", "light", "--spp", "2", "--chains", "64", "-q"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let meta = hslt::image::read_exr_metadata(&exr).unwrap();
    let get = |k: &str| meta.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    assert_eq!(get("hslt.mlt.hslt.direction").as_deref(), Some("light"));
    // Every HSLT walk of the render started at the light (the few proposals whose X is degenerate
    // never walk, hence not exactly 1).
    let from_light: f64 = get("hslt.mlt.hslt.mean.traced_from_light").unwrap().parse().unwrap();
    assert!(from_light > 0.99, "{from_light}");
    let f = data("base.xml");
    expect_error(
        &["render", f.to_str().unwrap(), "-o", "x.exr", "--hslt-direction", "sideways"],
        &["sideways"],
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_scene_nested_200000_deep_is_one_error_not_an_abort() {
    let dir = tmp_dir("deep");
    let path = dir.join("deep.xml");
    let n = 200_000;
    let xml = format!(
        "<scene version=\"3.0.0\">{}<bsdf type=\"diffuse\"/>{}</scene>",
        "<bsdf type=\"twosided\">".repeat(n),
        "</bsdf>".repeat(n)
    );
    std::fs::write(&path, xml).unwrap();
    let out = hslt().args(["info", path.to_str().unwrap()]).output().unwrap();
    assert_eq!(out.status.code(), Some(1), "stderr: {}", stderr(&out));
    expect_error(&["info", path.to_str().unwrap()], &["deep.xml:1:", "nested more than"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Sizes that inputs declare are checked against the memory this process can still allocate (plus a
/// limit set with `ulimit -v`) and, for images, against what the file's length can hold, so they fail
/// with one error naming the file instead of an abort.
/// huge-header.png was written with Python: the PNG signature, an IHDR chunk of 1000000 x 1000000
/// 8-bit RGB with its CRC, one tiny IDAT and IEND.
#[test]
fn declared_sizes_beyond_memory_are_errors_not_aborts() {
    const FINE_TEXTURE: &str = "texture=../../../docs/cbox.png";
    let scene = data("textured.xml");
    let scene = scene.to_str().unwrap();
    let out_dir = tmp_dir("sizes");
    let out = out_dir.join("x.exr");
    let out = out.to_str().unwrap();
    expect_error(
        &["render", scene, "-D", "resx=65536", "-D", FINE_TEXTURE, "--spp", "1", "-q", "-o", out],
        &["textured.xml:", "<film", "65536x65536 film needs", "GiB"],
    );
    expect_error(
        &["render", scene, "--spp", "1", "-q", "-o", out],
        &["huge-header.png", "1000000x1000000 image", "more than a file of 68 bytes can hold"],
    );
    // The same scene with a real texture renders.
    let ok =
        hslt().args(["render", scene, "-D", FINE_TEXTURE, "--spp", "1", "-q", "-o", out]).output().unwrap();
    assert!(ok.status.success(), "{}", stderr(&ok));
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// `--stats-json` (#32): for a pixel integrator and the Metropolis ones, a JSON document with the
/// render's statistics, equal to the `hslt.*` fields of the EXR header written beside it.
#[test]
fn stats_json_holds_the_render_statistics_of_every_integrator() {
    let dir = tmp_dir("stats");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    for integrator in ["pt", "bdpt", "pssmlt", "hslt+mlt"] {
        let json = dir.join(format!("{integrator}.json"));
        let exr = dir.join(format!("{integrator}.exr"));
        let out = hslt()
            .args(["render", scene.to_str().unwrap(), "-D", "resx=16", "-D", "resy=12", "--spp", "2"])
            .args(["--seed", "5", "--integrator", integrator, "-q", "-o", exr.to_str().unwrap()])
            .args(["--stats-json", json.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(out.status.success(), "{integrator}: {}", stderr(&out));
        let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(doc["integrator"], integrator, "{doc}");
        assert_eq!(doc["seed"], 5);
        assert_eq!((doc["width"].as_u64(), doc["height"].as_u64()), (Some(16), Some(12)));
        assert_eq!(doc["interrupted"], false);
        assert_eq!(doc["invalid_samples"], 0);
        let wall = doc["elapsed_seconds"].as_f64().unwrap();
        let cpu = doc["cpu_seconds"].as_f64().unwrap();
        // The process's CPU time comes in 10-ms ticks, and this render (without OpenImageIO's
        // start-up, now that it is loaded only for the formats that need it) can take less than one;
        // resources::tests checks that it grows with work.
        assert!(wall > 0.0 && cpu >= 0.0 && cpu.is_finite(), "{doc}");
        assert!(doc["rays"].as_u64().unwrap() > 0 && doc["samples"].as_u64().unwrap() > 0, "{doc}");
        // Rays by kind: every integrator here traces shadow rays to the box's area light.
        let (shadow, closest) =
            (doc["shadow_rays"].as_u64().unwrap(), doc["closest_hit_rays"].as_u64().unwrap());
        assert!(shadow > 0 && closest > 0, "{doc}");
        assert_eq!(shadow + closest, doc["rays"].as_u64().unwrap());
        assert!(doc["samples_per_second"].as_f64().unwrap() > 0.0);
        assert!(doc["peak_memory_bytes"].as_u64().unwrap() > 1 << 20);
        if integrator == "pt" || integrator == "bdpt" {
            assert_eq!(doc["spp"], 2);
            assert!(doc.get("mlt").is_none());
        } else {
            let mlt = &doc["mlt"];
            assert!(mlt["mutations"].as_u64().unwrap() > 0, "{doc}");
            let acceptance = mlt["acceptance"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&acceptance));
            assert!(mlt["chains_stuck"].is_u64() && mlt["longest_rejection_streak"].is_u64(), "{doc}");
            assert!((0.0..=1.0).contains(&mlt["stuck_share"].as_f64().unwrap()), "{doc}");
            if integrator == "hslt+mlt" {
                assert!(mlt["lens"]["proposed"].as_u64().unwrap() > 0, "{doc}");
                assert!(mlt["lens"]["microseconds_per_proposal"].as_f64().unwrap() > 0.0, "{doc}");
                assert!(mlt["hslt"]["proposed"].is_u64(), "{doc}");
            }
        }
        // The EXR header holds the same fields.
        let meta = hslt::image::read_exr_metadata(&exr).unwrap();
        let from_header = hslt::cli::stats_json::stats_document(&meta);
        assert_eq!(from_header, doc, "{integrator}: the EXR header and the JSON differ");
    }
    expect_error(
        &["render", scene.to_str().unwrap(), "-o", "x.exr", "--stats-json", "/nonexistent-dir/s.json"],
        &["--stats-json", "/nonexistent-dir"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--aov albedo,normal,depth` (#32): EXR layers named and channelled as OIDN and Blender expect,
/// albedo in [0, 1], unit normals and positive depths on geometry, the background's depth far away;
/// PNG outputs stay beauty only.
#[test]
fn aov_layers_hold_albedo_normals_and_depth() {
    let dir = tmp_dir("aov");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/materials/scene.xml");
    let exr = dir.join("aov.exr");
    let png = dir.join("aov.png");
    let out = hslt()
        .args(["render", scene.to_str().unwrap(), "-D", "resx=32", "-D", "resy=24", "--spp", "2", "-q"])
        .args(["--aov", "albedo,normal,depth", "-o", exr.to_str().unwrap(), "-o", png.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let layers = hslt::image::read_exr_layers(&exr).unwrap();
    let names: Vec<&str> = layers.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["combined", "albedo", "normal", "depth"]);
    let (albedo, normal, depth) = (&layers[1].1, &layers[2].1, &layers[3].1);
    assert_eq!((albedo.channels, normal.channels, depth.channels), (3, 3, 1));
    assert!(albedo.data.iter().all(|&a| (0.0..=1.0).contains(&a)));
    assert!(albedo.data.iter().any(|&a| a > 0.1), "the albedo is black");
    let mut unit = 0;
    for p in 0..depth.data.len() {
        let d = depth.data[p];
        assert!(d.is_finite() && d > 0.0, "pixel {p}: depth {d}");
        let n = &normal.data[p * 3..p * 3 + 3];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!(len <= 1.0 + 1e-4, "pixel {p}: |n| = {len}");
        // A pixel's normal is the mean over its samples: unit wherever they all saw one flat surface.
        if (len - 1.0).abs() < 1e-3 {
            unit += 1;
        }
    }
    assert!(unit * 2 > depth.data.len(), "only {unit} pixels have unit normals");
    // On the Cornell box most pixels see the white diffuse walls, whose albedo is their reflectance.
    let cbox = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let cbox_exr = dir.join("cbox.exr");
    let out = hslt()
        .args(["render", cbox.to_str().unwrap(), "-D", "resx=16", "-D", "resy=16", "--spp", "1", "-q"])
        .args(["--aov", "albedo", "-o", cbox_exr.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let cbox_albedo = &hslt::image::read_exr_layers(&cbox_exr).unwrap()[1].1;
    let white = cbox_albedo
        .data
        .chunks(3)
        .filter(|a| (a[0] - 0.725).abs() < 1e-3 && (a[1] - 0.71).abs() < 1e-3 && (a[2] - 0.68).abs() < 1e-3)
        .count();
    assert!(white * 3 > 16 * 16, "only {white} of 256 pixels have the walls' albedo");
    // The PNG is the beauty image alone.
    let png_image = hslt::image::read_image(&png, false).unwrap();
    assert_eq!(png_image.channels, 3);
    expect_error(&["render", scene.to_str().unwrap(), "-o", "x.png", "--aov", "albedo"], &["--aov", ".exr"]);
    expect_error(&["render", scene.to_str().unwrap(), "-o", "x.exr", "--aov", "albedo,uv"], &["--aov", "uv"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Reads tev packets (u32 little-endian length including itself, then a type byte) until the peer
/// closes; returns (type, payload) pairs.
fn read_tev_packets(mut socket: std::net::TcpStream) -> Vec<(u8, Vec<u8>)> {
    use std::io::Read;
    let mut packets = Vec::new();
    loop {
        let mut len = [0u8; 4];
        if socket.read_exact(&mut len).is_err() {
            return packets;
        }
        let len = u32::from_le_bytes(len) as usize;
        assert!(len >= 5, "a packet of {len} bytes");
        let mut body = vec![0u8; len - 4];
        socket.read_exact(&mut body).unwrap();
        packets.push((body[0], body[1..].to_vec()));
    }
}

/// `--tev` (#32) against a loopback listener that decodes what tev would receive: one create-image
/// packet naming the image and its size, then update-image packets whose rows cover the image; for
/// a pixel integrator and a Metropolis one. Without a listener, a warning and a normal render.
#[test]
fn tev_receives_a_create_and_updates_of_the_image() {
    const CREATE: u8 = 4;
    const UPDATE: u8 = 6;
    let dir = tmp_dir("tev");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    for (integrator, budget) in [("pt", ["--spp", "4"]), ("pssmlt", ["--time", "2.5"])] {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = listener.local_addr().unwrap().to_string();
        let reader = std::thread::spawn(move || read_tev_packets(listener.accept().unwrap().0));
        let out = dir.join(format!("{integrator}.exr"));
        let result = hslt()
            .args(["render", scene.to_str().unwrap(), "-D", "resx=100", "-D", "resy=70", "-q"])
            .args(["--integrator", integrator, "--tev", &address, "-o", out.to_str().unwrap()])
            .args(budget)
            .output()
            .unwrap();
        assert!(result.status.success(), "{integrator}: {}", stderr(&result));
        assert!(!stderr(&result).contains("warning"), "{}", stderr(&result));
        let packets = reader.join().unwrap();
        let creates: Vec<&Vec<u8>> = packets.iter().filter(|(t, _)| *t == CREATE).map(|(_, p)| p).collect();
        assert_eq!(creates.len(), 1, "{integrator}: {} create packets", creates.len());
        // grab_focus, the name (NUL-terminated), width, height, channel count.
        let name_end = creates[0][1..].iter().position(|&b| b == 0).unwrap() + 1;
        assert_eq!(&creates[0][1..name_end], format!("{integrator}.exr").as_bytes());
        let dims = &creates[0][name_end + 1..name_end + 13];
        let word = |k: usize| u32::from_le_bytes(dims[4 * k..4 * k + 4].try_into().unwrap());
        assert_eq!((word(0), word(1), word(2)), (100, 70, 3));
        let updates: Vec<&Vec<u8>> = packets.iter().filter(|(t, _)| *t == UPDATE).map(|(_, p)| p).collect();
        // The final image comes in two bands (64 rows, then 6); a 2.5 s render also sends snapshots.
        let min_updates = if integrator == "pt" { 2 } else { 4 };
        assert!(updates.len() >= min_updates, "{integrator}: {} update packets", updates.len());
        // The last band's pixels: 100 × 6 RGB floats after its header.
        let last = updates.last().unwrap();
        let floats = 100 * 6 * 3;
        assert!(last.len() > floats * 4, "{integrator}: last update of {} bytes", last.len());
        let data = &last[last.len() - floats * 4..];
        let values: Vec<f32> = data.chunks(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        assert!(values.iter().all(|v| v.is_finite() && *v >= 0.0), "{integrator}: {values:?}");
        assert!(values.iter().any(|&v| v > 0.0), "{integrator}: a black band");
    }
    // Nothing listening: one warning, and the render goes on.
    let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().to_string();
    let out = dir.join("alone.exr");
    let result = hslt()
        .args(["render", scene.to_str().unwrap(), "-D", "resx=8", "-D", "resy=8", "--spp", "1", "-q"])
        .args(["--tev", &free, "-o", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(result.status.success(), "{}", stderr(&result));
    assert_eq!(stderr(&result).matches("warning: --tev: no tev at").count(), 1, "{}", stderr(&result));
    assert!(out.is_file());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `hslt info scene | head -1`: a reader that stops early ends the command quietly (status 141, as
/// SIGPIPE would), not with a panic report.
#[test]
fn a_closed_output_pipe_is_not_a_panic() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let mut child = hslt()
        .arg("info")
        .arg(&scene)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Close the read end before the child can have written anything (it must start and load first).
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = stderr(&out);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(141), "{err}");
}

/// OpenImageIO is opened on first use (`libhslt_oiio.so`), not linked into the binary: an EXR render
/// never needs it, and a format that does is refused before the render when the shim cannot be
/// loaded, naming where it was looked for.
#[cfg(feature = "oiio")]
#[test]
fn openimageio_is_loaded_only_for_the_formats_that_need_it() {
    let dir = tmp_dir("oiio-shim");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box/scene.xml");
    let render = |outputs: &[&PathBuf], shim: &str| {
        let mut cmd = hslt();
        cmd.env("HSLT_OIIO_SHIM", shim).arg("render").arg(&scene);
        cmd.args(["-D", "resx=16", "-D", "resy=16", "--spp", "2", "-q"]);
        for o in outputs {
            cmd.arg("-o").arg(o);
        }
        cmd.output().unwrap()
    };
    let missing = dir.join("no-such-shim.so");
    let (exr, png) = (dir.join("a.exr"), dir.join("a.png"));
    let out = render(&[&exr], missing.to_str().unwrap());
    assert!(out.status.success(), "an EXR render needed the shim: {}", stderr(&out));
    assert!(exr.is_file());
    let (exr2, png2) = (dir.join("b.exr"), dir.join("b.png"));
    let out = render(&[&exr2, &png2], missing.to_str().unwrap());
    let err = stderr(&out);
    assert!(!out.status.success(), "a PNG without the shim succeeded");
    assert!(err.contains("no-such-shim.so") && err.contains("HSLT_OIIO_SHIM"), "{err}");
    assert!(!exr2.exists() && !png2.exists(), "the render ran before the output check");
    // The build's own shim writes the PNG.
    let built = hslt::image::built_oiio_shim_path().to_str().unwrap().to_string();
    let out = render(&[&png], &built);
    assert!(out.status.success() && png.is_file(), "{}", stderr(&out));
    let _ = std::fs::remove_dir_all(&dir);
}
