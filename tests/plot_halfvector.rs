//! The supplement's half-vector plots (`manifold::sweep`, `hslt plot-halfvector`) on a rough conductor
//! plane seen by a camera in the mirror position of a small area light: f_H at the path's own half vector,
//! the specular peak of the sweep, and the CLI's output and errors.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec2;
use hslt::manifold::sweep::{find_path, grid_half_vector, HalfVectorSweep, PathSearch, SweepError};
use hslt::manifold::{path_constraints, path_etas, path_geometry};
use hslt::path::{PathView, Vertex};
use hslt::scene::{LoadOptions, Scene};

const RESOLUTION: usize = 32;

/// Camera at (−2, 0, 2) and a 0.2 × 0.2 light at (2, 0, 2), both facing the origin of a Beckmann
/// α = 0.2 conductor plane z = 0: the centre pixel sees the mirror reflection of the light.
fn scene_xml() -> String {
    format!(
        r#"<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="30" />
    <transform name="to_world"><lookat origin="-2, 0, 2" target="0, 0, 0" up="0, 0, 1" /></transform>
    <film type="hdrfilm"><integer name="width" value="{RESOLUTION}" /><integer name="height" value="{RESOLUTION}" /></film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="10" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="0.2" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.1" /><lookat origin="2, 0, 2" target="0, 0, 0" up="0, 0, 1" /></transform>
    <emitter type="area"><rgb name="radiance" value="10, 10, 10" /></emitter>
  </shape>
</scene>"#
    )
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hslt-plot-hv-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write_scene(dir: &Path) -> PathBuf {
    let path = dir.join("plane.xml");
    std::fs::write(&path, scene_xml()).unwrap();
    path
}

fn load_scene(name: &str) -> Scene {
    let dir = temp_dir(name);
    let scene = Scene::load(&write_scene(&dir), &LoadOptions::default()).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    scene
}

fn centre_path(scene: &Scene) -> Vec<Vertex> {
    let c = RESOLUTION as u32 / 2;
    let search = PathSearch { pixel: (c, c), vertex: 1, max_vertices: 3, seed: 1, attempts: 64 };
    let path = find_path(scene, &search).unwrap();
    assert_eq!(path.len(), 3, "camera, plane, light");
    path
}

/// f_A / |det J| from the path primitives, independently of the sweep module.
fn f_h(scene: &Scene, path: &[Vertex]) -> f64 {
    let f_a = hslt::spectrum::luminance(PathView::whole(path).contribution(scene)) as f64;
    let constraints = path_constraints(&path_geometry(path), &path_etas(scene, path)).unwrap();
    f_a / constraints.jacobian.factor().unwrap().log_det().value().abs()
}

fn relative_error(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn contribution_at_the_paths_own_half_vector_is_its_f_a_over_det_j() {
    let scene = load_scene("own");
    let path = centre_path(&scene);
    let expected = f_h(&scene, &path);
    assert!(expected > 0.0);
    let sweep = HalfVectorSweep::new(&scene, &path, 1).unwrap();
    let own = sweep.half_vectors()[0];
    let at_own = sweep.evaluate(own).expect("the walk to the path's own half vector");
    assert!(relative_error(at_own.measurement.contribution, expected) < 1e-3);
    // Away and back again: the walk must return to the same path and the same f_H.
    let away = sweep.evaluate(own + DVec2::new(0.15, -0.1)).expect("a walk to a nearby half vector");
    assert!(relative_error(away.measurement.contribution, expected) > 0.05, "moving h must change f_H");
    let back = sweep.evaluate_from(&away.path, own).expect("the walk back");
    assert!((back.path[1].p - path[1].p).length() < 1e-4, "{:?} vs {:?}", back.path[1].p, path[1].p);
    let rel = relative_error(back.measurement.contribution, expected);
    assert!(rel < 1e-3, "f_H after walking back {} vs {expected} ({rel})", back.measurement.contribution);
}

#[test]
fn rough_conductor_sweep_peaks_at_the_specular_configuration() {
    let scene = load_scene("peak");
    let path = centre_path(&scene);
    let result = HalfVectorSweep::new(&scene, &path, 1).unwrap().sweep(41);
    let disk_cells = (0..41 * 41).filter(|&i| grid_half_vector(41, i % 41, i / 41).is_some()).count();
    let valid = result.valid.iter().filter(|&&v| v).count();
    // The film cuts the plane off at about |h| = 0.25, so only part of the disk is reachable.
    assert!(valid > disk_cells / 20, "{valid} of {disk_cells} cells valid");
    let peak = result.contribution_peak().unwrap();
    // Cells are 0.049 wide and the light's 0.2 m extent moves the mirror point by up to ~0.03 in h.
    assert!(peak.length() < 0.08, "contribution peaks at {peak:?}");
    let (contribution, bsdf, difference) = result.normalised();
    let centre = 20 * 41 + 20;
    assert!(contribution[centre] > 0.8 && bsdf[centre] > 0.8, "{} {}", contribution[centre], bsdf[centre]);
    // The supplement's observation: f_H follows the local BSDF closely in half-vector space.
    let mean_difference = difference.iter().sum::<f64>() / valid as f64;
    assert!(mean_difference < 0.1, "mean normalised difference {mean_difference}");
    // And the lobe falls off: a Beckmann α = 0.2 lobe is ~e^-4 at |h| = 0.4.
    let off_peak = (0..result.valid.len())
        .filter(|&i| result.valid[i])
        .filter(|&i| grid_half_vector(41, i % 41, i / 41).unwrap().length() > 0.4)
        .map(|i| contribution[i])
        .fold(0.0, f64::max);
    assert!(off_peak < 0.1, "contribution {off_peak} far from the peak");
}

#[test]
fn a_vertex_beyond_the_path_or_the_depth_limit_is_a_clear_error() {
    let scene = load_scene("errors");
    let search = PathSearch { pixel: (16, 16), vertex: 2, max_vertices: 4, seed: 0, attempts: 8 };
    // The plane is the only scatterer: the second vertex is never a scattering vertex before the light.
    let err = find_path(&scene, &search).unwrap_err();
    assert!(matches!(err, SweepError::NoPath { vertex: 2, attempts: 8, .. }), "{err}");
    let err = find_path(&scene, &PathSearch { vertex: 0, ..search }).unwrap_err();
    assert!(matches!(err, SweepError::VertexOutOfRange { vertex: 0, .. }), "{err}");
    let path = centre_path(&scene);
    assert!(matches!(
        HalfVectorSweep::new(&scene, &path, 2),
        Err(SweepError::NotInner { vertex: 2, len: 3 })
    ));
}

fn hslt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hslt"))
}

fn expect_error(args: &[&str], needle: &str) {
    let out = hslt().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{args:?}: {err}");
    assert!(lines[0].contains(needle), "'{needle}' missing from: {}", lines[0]);
}

#[test]
fn cli_writes_three_polar_plots_and_rejects_bad_input() {
    let dir = temp_dir("cli");
    let scene = write_scene(&dir);
    let scene = scene.to_str().unwrap();
    let out = dir.join("plot.png");
    let status = hslt()
        .args(["plot-halfvector", scene, "--pixel", "16,16", "--vertex", "1", "--resolution", "24", "-o"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let image = hslt::image::read_image(&out, false).unwrap();
    // Three 24-pixel panels with 2-pixel gaps, RGBA.
    assert_eq!((image.width, image.height, image.channels), (3 * 24 + 2 * 2, 24, 4));
    assert_eq!(image.pixel(0, 0)[3], 0.0, "outside the disk is transparent");
    assert_eq!(image.pixel(12, 12)[3], 1.0, "the disk is opaque");
    let centre = image.pixel(12, 12);
    assert!(centre[0] > 0.5 && centre[1] > 0.5, "the centre of the contribution plot is bright: {centre:?}");

    let o = out.to_str().unwrap();
    expect_error(
        &["plot-halfvector", scene, "--pixel", "16,16", "--vertex", "9", "-o", o],
        "vertex index 9 is out of range",
    );
    expect_error(
        &["plot-halfvector", scene, "--pixel", "40,3", "--vertex", "1", "-o", o],
        "pixel (40, 3) is outside the 32x32 image",
    );
    expect_error(&["plot-halfvector", scene, "--pixel", "16", "--vertex", "1", "-o", o], "expected X,Y");
    expect_error(
        &["plot-halfvector", scene, "--pixel", "16,16", "--vertex", "2", "--attempts", "4", "-o", o],
        "no path through pixel",
    );
    expect_error(
        &["plot-halfvector", scene, "--pixel", "16,16", "--vertex", "1", "-o", "plot.exr"],
        "expected a name ending in .png",
    );
    std::fs::remove_dir_all(&dir).ok();
}
