//! Integration tests of the Mitsuba XML parser: the shared scenes, defines, errors with positions,
//! 0.6 → 3.x upgrade, and transform composition against hand-computed matrices.

mod common;

use glam::{Mat4, Vec3};
use hslt::scene::xml::parse_file;
use hslt::scene::{PropValue, Props, SceneError};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/scene").join(rel)
}

fn top<'a>(scene: &'a Props, tag: &'a str) -> Vec<&'a Arc<Props>> {
    scene.objects_with_tag(tag).collect()
}

fn err_of(rel: &str) -> SceneError {
    match parse_file(&data(rel), &[]) {
        Ok(_) => panic!("{rel} parsed but should not"),
        Err(e) => e,
    }
}

#[test]
fn shared_scenes_parse_with_expected_counts() {
    let dir = common::shared_scenes();
    // (scene, shapes, top-level bsdfs, emitters nested in shapes)
    for (name, shapes, bsdfs, emitters) in [
        ("cornell-box", 8, 8, 1),
        ("veach-mis", 9, 6, 3),
        ("veach-bidir", 14, 4, 2),
        ("veach-ajar", 22, 13, 1),
    ] {
        let scene = parse_file(&dir.join(name).join("scene.xml"), &[]).unwrap();
        assert_eq!(scene.tag, "scene");
        assert!(scene.entries.iter().all(|p| p.name.is_empty()), "{name}");
        let shape_list = top(&scene, "shape");
        assert_eq!(shape_list.len(), shapes, "{name} shapes");
        assert_eq!(top(&scene, "bsdf").len(), bsdfs, "{name} bsdfs");
        let n_emitters: usize = shape_list.iter().map(|s| s.objects_with_tag("emitter").count()).sum();
        assert_eq!(n_emitters, emitters, "{name} emitters");
        assert_eq!(top(&scene, "integrator").len(), 1);
        let integrator = top(&scene, "integrator")[0];
        assert_eq!(integrator.plugin_type, "path", "$integrator default");
        let sensor = top(&scene, "sensor")[0];
        let sampler = sensor.objects_with_tag("sampler").next().unwrap();
        assert_eq!(sampler.int("sample_count", 0).unwrap(), 64);
        // Every shape has exactly one BSDF, and <ref>s share the declared object.
        for s in &shape_list {
            let b: Vec<_> = s.objects_with_tag("bsdf").collect();
            assert_eq!(b.len(), 1, "{name} {:?}", s.id);
            let id = b[0].id.as_deref().unwrap();
            let declared = top(&scene, "bsdf").into_iter().find(|d| d.id.as_deref() == Some(id)).unwrap();
            assert!(Arc::ptr_eq(b[0], declared), "ref to {id} must share, not copy");
        }
    }
}

#[test]
fn cornell_box_values_and_locations() {
    let dir = common::shared_scenes();
    let path = dir.join("cornell-box/scene.xml");
    let scene = parse_file(&path, &[]).unwrap();
    let sensor = top(&scene, "sensor")[0];
    assert_eq!(sensor.float("fov", 0.0).unwrap(), 19.5);
    assert_eq!((sensor.loc.line, sensor.loc.col), (14, 2));
    assert_eq!(*sensor.loc.file, path);
    let m = sensor.transform("to_world").unwrap();
    let expect = Mat4::from_cols_array(&[
        -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 6.8, 1.0,
    ]);
    assert!(m.abs_diff_eq(expect, 1e-6), "{m:?}");
    let film = sensor.objects_with_tag("film").next().unwrap();
    assert_eq!(film.int("width", 0).unwrap(), 1024);
    assert_eq!(film.string("pixel_format", "").unwrap(), "rgb");
    let left = top(&scene, "bsdf")[0];
    assert_eq!(left.id.as_deref(), Some("LeftWallBSDF"));
    let inner = left.objects_with_tag("bsdf").next().unwrap();
    assert_eq!(inner.rgb("reflectance", Vec3::ZERO).unwrap(), Vec3::new(0.63, 0.065, 0.05));
    let light = top(&scene, "shape").into_iter().find(|s| s.id.as_deref() == Some("Light")).unwrap();
    let em = light.objects_with_tag("emitter").next().unwrap();
    assert_eq!(em.rgb("radiance", Vec3::ZERO).unwrap(), Vec3::new(17.0, 12.0, 4.0));
}

#[test]
fn defines_override_defaults() {
    let dir = common::shared_scenes();
    let defines = vec![("spp".to_string(), "16".to_string()), ("integrator".to_string(), "bdpt".to_string())];
    let scene = parse_file(&dir.join("veach-mis/scene.xml"), &defines).unwrap();
    let sensor = top(&scene, "sensor")[0];
    let sampler = sensor.objects_with_tag("sampler").next().unwrap();
    assert_eq!(sampler.int("sample_count", 0).unwrap(), 16);
    let integrator = top(&scene, "integrator")[0];
    assert_eq!(integrator.plugin_type, "bdpt");
    assert_eq!(integrator.int("max_depth", 0).unwrap(), 3, "untouched default");
}

#[test]
fn undefined_parameter_names_it_and_suggests_define() {
    let e = err_of("bad/undefined_param.xml");
    let msg = e.to_string();
    assert_eq!(e.loc.line, 4, "{msg}");
    assert!(msg.contains("$sample_count"), "{msg}");
    assert!(msg.contains("-D sample_count=value"), "{msg}");
    // ...and the define makes it parse.
    let ok = parse_file(&data("bad/undefined_param.xml"), &[("sample_count".into(), "9".into())]).unwrap();
    let s = top(&ok, "sampler")[0];
    assert_eq!(s.int("sample_count", 0).unwrap(), 9);
}

#[test]
fn malformed_xml_reports_line() {
    let e = err_of("bad/unclosed.xml");
    assert!(e.message.contains("malformed XML"), "{e}");
    assert_eq!(e.loc.line, 7, "{e}");
    assert!(e.to_string().contains("unclosed.xml:7:"), "{e}");
    let e = err_of("bad/mismatched_quote.xml");
    assert!(e.message.contains("malformed XML"), "{e}");
    assert!((3..=5).contains(&e.loc.line), "{e}");
    let e = err_of("bad/dtd_entity.xml");
    assert!(e.message.contains("malformed XML"), "DTDs are refused: {e}");
}

#[test]
fn unknown_and_unsupported_elements() {
    let e = err_of("bad/unknown_tag.xml");
    assert_eq!(e.loc.line, 5, "{e}");
    assert!(e.message.contains("unknown element <floot>"), "{e}");
    let e = err_of("bad/medium.xml");
    assert!(e.message.contains("<medium> is not supported"), "{e}");
    assert_eq!(e.loc.line, 2);
}

#[test]
fn bad_values_and_ids() {
    let e = err_of("bad/bad_number.xml");
    assert_eq!(e.loc.line, 3, "{e}");
    assert!(e.message.contains("'value'") && e.message.contains("\"4o\""), "{e}");
    let e = err_of("bad/no_version.xml");
    assert!(e.message.contains("version"), "{e}");
    let e = err_of("bad/duplicate_id.xml");
    assert!(e.message.contains("duplicate id 'wall'") && e.message.contains("line 2"), "{e}");
    assert_eq!(e.loc.line, 3);
    let e = err_of("bad/unknown_ref.xml");
    assert!(e.message.contains("unknown id 'wal'"), "{e}");
    assert_eq!(e.loc.line, 4);
    let e = err_of("bad/spectrum_samples.xml");
    assert!(e.message.contains("uniform spectra only"), "{e}");
}

/// Structural equality ignoring source locations (the two files differ in line numbers).
fn same_ignoring_loc(a: &Props, b: &Props, path: &str) {
    assert_eq!(a.tag, b.tag, "{path}");
    assert_eq!(a.plugin_type, b.plugin_type, "{path}");
    assert_eq!(a.id, b.id, "{path}");
    assert_eq!(
        a.entries.len(),
        b.entries.len(),
        "{path}: {:?} vs {:?}",
        a.entries.iter().map(|p| &p.name).collect::<Vec<_>>(),
        b.entries.iter().map(|p| &p.name).collect::<Vec<_>>()
    );
    for (x, y) in a.entries.iter().zip(&b.entries) {
        let here = format!("{path}/{}", x.name);
        assert_eq!(x.name, y.name, "{here}");
        match (&x.value, &y.value) {
            (PropValue::Object(p), PropValue::Object(q)) => same_ignoring_loc(p, q, &here),
            (PropValue::Transform(p), PropValue::Transform(q)) => {
                assert!(p.abs_diff_eq(*q, 1e-6), "{here}")
            }
            (p, q) => assert_eq!(p, q, "{here}"),
        }
    }
}

#[test]
fn legacy_camel_case_matches_modern_spelling() {
    let old = parse_file(&data("legacy_06.xml"), &[]).unwrap();
    let new = parse_file(&data("modern_3x.xml"), &[]).unwrap();
    same_ignoring_loc(&old, &new, "scene");
    // Spot checks that the names really are the Mitsuba 3 ones.
    let glass = top(&old, "bsdf")[0];
    assert_eq!(glass.float("int_ior", 0.0).unwrap(), 1.5);
    let white = top(&old, "bsdf")[1];
    assert!(white.has("reflectance"), "diffuseReflectance → reflectance");
    let integrator = top(&old, "integrator")[0];
    assert_eq!(integrator.int("max_depth", 0).unwrap(), 8, "$maxDepth default kept its name");
    assert_eq!(integrator.int("rr_depth", 0).unwrap(), 3);
    let sphere = top(&new, "shape")[1];
    let em = sphere.objects_with_tag("emitter").next().unwrap();
    assert_eq!(em.rgb("radiance", Vec3::ZERO).unwrap(), Vec3::splat(3.0));
    assert!(sphere.object("bsdf").unwrap().is_some(), "named <ref>");
}

fn shape<'a>(scene: &'a Props, id: &str) -> &'a Arc<Props> {
    scene.objects().map(|(_, o)| o).find(|o| o.id.as_deref() == Some(id)).unwrap()
}

fn maps(m: Mat4, from: Vec3, to: Vec3) {
    let got = m.transform_point3(from);
    assert!((got - to).length() < 1e-5, "{from:?} → {got:?}, expected {to:?}");
}

#[test]
fn transforms_compose_in_document_order() {
    let scene = parse_file(&data("transforms.xml"), &[]).unwrap();
    // translate(1,2,3), then rotate z 90°, then scale (2,3,4): p ↦ S·R·T·p.
    let m = shape(&scene, "composed").transform("to_world").unwrap();
    let expect = Mat4::from_scale(Vec3::new(2.0, 3.0, 4.0))
        * Mat4::from_rotation_z(90f32.to_radians())
        * Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0));
    assert!(m.abs_diff_eq(expect, 1e-5), "{m:?}");
    maps(m, Vec3::ZERO, Vec3::new(-4.0, 3.0, 12.0));
    maps(m, Vec3::X, Vec3::new(-4.0, 6.0, 12.0));

    // Right-handed rotation: +90° about x takes +y to +z.
    let m = shape(&scene, "rotate_value").transform("to_world").unwrap();
    maps(m, Vec3::Y, Vec3::Z);
    maps(m, Vec3::Z, -Vec3::Y);

    let m = shape(&scene, "uniform_scale").transform("to_world").unwrap();
    maps(m, Vec3::new(1.0, 1.0, 1.0), Vec3::new(4.0, 5.0, 6.0));

    // The matrix is row-major: its first column (0, 1, 0) is the image of +x.
    let m = shape(&scene, "matrix_then_translate").transform("to_world").unwrap();
    maps(m, Vec3::X, Vec3::new(0.0, 1.0, 5.0));

    // lookat origin 0, target +x, up +z: columns [left, up, dir] = [y, z, x].
    let m = shape(&scene, "cam").transform("to_world").unwrap();
    maps(m, Vec3::X, Vec3::Y);
    maps(m, Vec3::Y, Vec3::Z);
    maps(m, Vec3::Z, Vec3::X);

    let s = shape(&scene, "point_forms");
    assert_eq!(s.get("center").unwrap().value, PropValue::Point(Vec3::new(1.0, 2.0, 3.0)));
    assert_eq!(s.get("axis").unwrap().value, PropValue::Vector(Vec3::new(4.0, 0.0, 6.0)));
}

#[test]
fn missing_file_is_a_clear_error() {
    let e = parse_file(&data("does_not_exist.xml"), &[]).unwrap_err();
    assert!(e.to_string().contains("does_not_exist.xml"), "{e}");
    assert!(e.message.contains("cannot read scene file"), "{e}");
}

/// A scene whose plugins nest `levels` deep below `<scene>` (each level a `twosided` holding the next),
/// with a comment holding a start tag and an attribute value holding "/>" at every level, which the
/// nesting scan must not count.
fn nested_scene(levels: usize) -> String {
    let mut xml = String::from("<?xml version=\"1.0\"?>\n<!-- <bsdf> in a comment opens nothing -->\n");
    xml.push_str("<scene version=\"3.0.0\">\n");
    for _ in 1..levels {
        xml.push_str("<bsdf type=\"twosided\" name=\"x/>y\"><!-- <bsdf type=\"a\"> -->\n");
    }
    xml.push_str("<bsdf type=\"diffuse\"/>\n");
    for _ in 1..levels {
        xml.push_str("</bsdf>\n");
    }
    xml.push_str("</scene>\n");
    xml
}

#[test]
fn nesting_beyond_the_limit_is_an_error_not_a_stack_overflow() {
    use hslt::scene::xml::{parse_str, MAX_NESTING};
    let path = Path::new("deep.xml");
    // <scene> is level 1, so MAX_NESTING - 1 plugin levels below it is the deepest accepted document.
    let at_limit = parse_str(&nested_scene(MAX_NESTING - 1), path, &[]).unwrap();
    let mut levels = 1;
    let mut props = at_limit.entries[0].value.clone();
    while let PropValue::Object(inner) = props {
        levels += 1;
        props = inner.entries.first().map_or(PropValue::Bool(false), |e| e.value.clone());
    }
    assert_eq!(levels, MAX_NESTING, "every level of the accepted document was read");
    let over = parse_str(&nested_scene(MAX_NESTING), path, &[]).unwrap_err();
    assert!(over.message.contains(&format!("nested more than {MAX_NESTING} deep")), "{over}");
    // Line 3 is <scene>, so the first element too deep (level MAX_NESTING + 1) is on line MAX_NESTING + 3.
    assert_eq!(over.loc.line as usize, MAX_NESTING + 3, "{over}");
    assert!(over.to_string().starts_with("deep.xml:"), "{over}");
    // Far beyond it, where roxmltree's recursive tokenizer would overflow the stack.
    let abyss = parse_str(&nested_scene(200_000), path, &[]).unwrap_err();
    assert!(abyss.message.contains("nested more than"), "{abyss}");
}

/// `<include>` (Mitsuba's): main.xml assembles merged.xml from three files in parts/, one of them
/// included by another part (relative to that part), with `$param` substitution in a file name, ids
/// declared in one part and referenced in another, and a mesh named in a part that resolves against
/// the scene's directory. Both files must give the same image, bit for bit.
#[test]
fn a_scene_split_across_included_files_renders_as_the_merged_file() {
    use hslt::cli::{load_scene, render_scene};
    use hslt::registry::IntegratorKind;
    let split = load_scene(&data("include/main.xml"), &[]).unwrap();
    let merged = load_scene(&data("include/merged.xml"), &[]).unwrap();
    assert_eq!(split.shapes.len(), 4);
    assert_eq!(split.lights.len(), merged.lights.len());
    let (a, _) = render_scene(&split, IntegratorKind::Path, 4, 3);
    let (b, _) = render_scene(&merged, IntegratorKind::Path, 4, 3);
    let mean = b.data.iter().map(|&x| x as f64).sum::<f64>() / b.data.len() as f64;
    assert!(mean > 0.01, "the merged scene renders black ({mean})");
    assert_eq!(a.data, b.data, "the included scene renders differently from the merged one");
    // The errors of an included file name that file and line, and where it was included.
    let e = parse_file(&data("include/broken-main.xml"), &[]).unwrap_err().to_string();
    assert!(e.contains("parts/broken.xml:3:"), "{e}");
    assert!(e.contains("included at") && e.contains("broken-main.xml:3:"), "{e}");
}

#[test]
fn an_include_cycle_is_an_error_naming_the_chain_of_files() {
    let e = parse_file(&data("include/cycle-a.xml"), &[]).unwrap_err().to_string();
    assert!(e.contains("<include> cycle: "), "{e}");
    let chain = e.split("<include> cycle: ").nth(1).unwrap();
    let files: Vec<&str> = chain.split(" includes ").collect();
    assert_eq!(files.len(), 3, "{e}");
    assert!(files[0].ends_with("cycle-a.xml") && files[1].ends_with("cycle-b.xml"), "{e}");
    assert!(files[2].starts_with(&*data("include/cycle-a.xml").to_string_lossy()), "{e}");
    // A missing file, and a file that includes itself, are errors too.
    let dir = std::env::temp_dir().join(format!("hslt-include-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let me = dir.join("self.xml");
    std::fs::write(&me, "<scene version=\"3.0.0\"><include filename=\"self.xml\"/></scene>").unwrap();
    let e = parse_file(&me, &[]).unwrap_err().to_string();
    assert!(e.contains("cycle") && e.contains("self.xml includes"), "{e}");
    let missing = dir.join("missing.xml");
    std::fs::write(&missing, "<scene version=\"3.0.0\">\n<include filename=\"nowhere.xml\"/></scene>")
        .unwrap();
    let e = parse_file(&missing, &[]).unwrap_err().to_string();
    assert!(e.contains("missing.xml:2:1") && e.contains("nowhere.xml"), "{e}");
    // Only regular files: /dev/zero would be read forever.
    let zero = dir.join("zero.xml");
    std::fs::write(&zero, "<scene version=\"3.0.0\"><include filename=\"/dev/zero\"/></scene>").unwrap();
    let e = parse_file(&zero, &[]).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
    // A chain of distinct files deeper than the limit.
    let depth = hslt::scene::xml::MAX_INCLUDE_DEPTH + 2;
    for k in 0..depth {
        let body =
            if k + 1 < depth { format!("<include filename=\"d{}.xml\"/>", k + 1) } else { String::new() };
        std::fs::write(dir.join(format!("d{k}.xml")), format!("<scene version=\"3.0.0\">{body}</scene>"))
            .unwrap();
    }
    let e = parse_file(&dir.join("d0.xml"), &[]).unwrap_err().to_string();
    assert!(e.contains("nested more than"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
