//! Integration tests of the shape loaders: every shape of the shared scenes, analytic shapes'
//! normals/uvs/areas, PLY/OBJ edge cases (truncation, NaN, degenerate triangles, missing files).

mod common;

use glam::{Mat4, Vec2, Vec3};
use hslt::geometry::TriangleMesh;
use hslt::scene::shapes::{load_shape, sphere_resolution, LoadedShape};
use hslt::scene::xml::parse_str;
use hslt::scene::{PropValue, Props, SceneError, SrcLoc};
use std::f32::consts::PI;
use std::path::{Path, PathBuf};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/scene")
}

/// Parses a one-shape scene snippet and loads its shape relative to the fixture directory.
fn load_xml(shape_xml: &str) -> Result<LoadedShape, SceneError> {
    let text = format!("<scene version=\"3.0.0\">\n{shape_xml}\n</scene>");
    let scene = parse_str(&text, &data_dir().join("inline.xml"), &[]).unwrap();
    let shape = scene.objects_with_tag("shape").next().unwrap().clone();
    load_shape(&shape, &data_dir())
}

fn mesh_file(kind: &str, file: &str, extra: &str) -> Result<LoadedShape, SceneError> {
    load_xml(&format!(
        "<shape type=\"{kind}\">\n<string name=\"filename\" value=\"meshes/{file}\"/>{extra}</shape>"
    ))
}

fn total_area(m: &TriangleMesh) -> f32 {
    (0..m.triangle_count()).map(|t| m.area(t)).sum()
}

/// Finite, unit normals, and geometric normals on the side the shading normals point to.
fn check_mesh(m: &TriangleMesh, what: &str) {
    assert!(m.triangle_count() > 0, "{what}");
    assert!(m.positions.iter().all(|p| p.is_finite()), "{what}");
    for t in 0..m.triangle_count() {
        let ng = m.geometric_normal(t);
        assert!((ng.length() - 1.0).abs() < 1e-3, "{what}: triangle {t} ng {ng:?}");
        if let Some(ns) = &m.normals {
            let [a, b, c] = m.indices[t];
            let avg = ns[a as usize] + ns[b as usize] + ns[c as usize];
            assert!(avg.dot(ng) > 0.0, "{what}: triangle {t} shading vs geometric");
        }
    }
    if let Some(ns) = &m.normals {
        assert_eq!(ns.len(), m.positions.len(), "{what}");
        for n in ns {
            assert!((n.length() - 1.0).abs() < 1e-4, "{what}: normal {n:?}");
        }
    }
    if let Some(uv) = &m.uvs {
        assert_eq!(uv.len(), m.positions.len(), "{what}");
        assert!(uv.iter().all(|u| u.is_finite()), "{what}");
    }
}

#[test]
fn all_shapes_of_shared_scenes_load() {
    let dir = common::shared_scenes();
    for name in ["cornell-box", "veach-mis", "veach-bidir", "veach-ajar"] {
        let scene_dir = dir.join(name);
        let scene = hslt::scene::xml::parse_file(&scene_dir.join("scene.xml"), &[]).unwrap();
        let mut n = 0;
        for shape in scene.objects_with_tag("shape") {
            let loaded = load_shape(shape, &scene_dir).unwrap_or_else(|e| panic!("{name}: {e}"));
            let what = format!("{name}/{}", loaded.mesh.name);
            check_mesh(&loaded.mesh, &what);
            assert!(loaded.warnings.iter().all(|w| !w.contains("re-wound")), "{what}: {:?}", loaded.warnings);
            if shape.bool("face_normals", false).unwrap() {
                assert!(loaded.mesh.normals.is_none(), "{what}: face_normals drops normals");
            }
            n += 1;
        }
        assert!(n > 0);
    }
}

#[test]
fn shared_scene_specifics() {
    let dir = common::shared_scenes();
    // veach-mis: the 0.05-radius light sphere keeps its area within 1e-3.
    let scene = hslt::scene::xml::parse_file(&dir.join("veach-mis/scene.xml"), &[]).unwrap();
    let small = scene.objects_with_tag("shape").find(|s| s.id.as_deref() == Some("Null_0003")).unwrap();
    let m = load_shape(small, &dir.join("veach-mis")).unwrap().mesh;
    let r = 0.05f32;
    assert!((total_area(&m) / (4.0 * PI * r * r) - 1.0).abs() < 1e-3);
    let c = m.bounds().center();
    assert!((c - Vec3::new(0.0, 6.5, 2.7)).length() < 1e-4, "{c:?}");

    // veach-ajar teapot (binary PLY with normals and uvs; uvs not flipped for PLY).
    let scene = hslt::scene::xml::parse_file(&dir.join("veach-ajar/scene.xml"), &[]).unwrap();
    let pot = scene.objects_with_tag("shape").find(|s| s.id.as_deref() == Some("Pot2_0001")).unwrap();
    let m = load_shape(pot, &dir.join("veach-ajar")).unwrap().mesh;
    assert!(m.normals.is_some() && m.uvs.is_some());
    assert!(m.triangle_count() > 10_000, "{}", m.triangle_count());
}

#[test]
fn sphere_area_within_1e3() {
    let (rings, segments) = sphere_resolution();
    for (radius, scale) in [(1.0f32, 1.0f32), (2.5, 1.0), (0.5, 3.0)] {
        let s = load_xml(&format!(
            "<shape type=\"sphere\"><float name=\"radius\" value=\"{radius}\"/>\
             <point name=\"center\" x=\"1\" y=\"-2\" z=\"3\"/>\
             <transform name=\"to_world\"><scale value=\"{scale}\"/></transform></shape>"
        ))
        .unwrap();
        let m = &s.mesh;
        check_mesh(m, "sphere");
        let r = radius * scale;
        let rel = total_area(m) / (4.0 * PI * r * r) - 1.0;
        assert!(rel.abs() < 1e-3, "r={r}: relative area error {rel} at {rings}x{segments}");
        // Analytic normals: radial from the (transformed) centre.
        let centre = Vec3::new(1.0, -2.0, 3.0) * scale;
        let ns = m.normals.as_ref().unwrap();
        for (p, n) in m.positions.iter().zip(ns) {
            assert!(((*p - centre) / r - *n).length() < 1e-4);
            assert!(((*p - centre).length() / r - 1.0).abs() < 1e-4);
        }
        // uv = (φ/2π, θ/π) with θ measured from +z.
        let uvs = m.uvs.as_ref().unwrap();
        for (n, uv) in ns.iter().zip(uvs) {
            let theta = n.z.clamp(-1.0, 1.0).acos();
            assert!((uv.y - theta / PI).abs() < 1e-3, "{n:?} {uv:?}");
            if n.z.abs() < 0.999 {
                let mut phi = n.y.atan2(n.x);
                if phi < 0.0 {
                    phi += 2.0 * PI;
                }
                let du = (uv.x - phi / (2.0 * PI)).abs();
                assert!(du < 1e-3 || (du - 1.0).abs() < 1e-3, "{n:?} {uv:?}");
            }
        }
    }
}

#[test]
fn rectangle_normals_uvs_and_transform() {
    let s = load_xml(
        "<shape type=\"rectangle\"><transform name=\"to_world\">\
         <scale x=\"2\" y=\"3\"/><rotate x=\"1\" angle=\"90\"/></transform></shape>",
    )
    .unwrap();
    let m = &s.mesh;
    check_mesh(m, "rectangle");
    assert!((total_area(m) - 24.0).abs() < 1e-4);
    // +z rotated 90° about x is −y.
    for n in m.normals.as_ref().unwrap() {
        assert!((*n + Vec3::Y).length() < 1e-5, "{n:?}");
    }
    for t in 0..m.triangle_count() {
        assert!((m.geometric_normal(t) + Vec3::Y).length() < 1e-5);
    }
    // uv = ((x+1)/2, (y+1)/2) of the object-space corner: recover x from the world position.
    for (p, uv) in m.positions.iter().zip(m.uvs.as_ref().unwrap()) {
        let x = p.x / 2.0;
        let y = p.z / 3.0; // object y ↦ world z after the rotation
        assert!((uv.x - (x + 1.0) / 2.0).abs() < 1e-5, "{p:?} {uv:?}");
        assert!((uv.y - (y + 1.0) / 2.0).abs() < 1e-5, "{p:?} {uv:?}");
    }
}

#[test]
fn cube_faces_point_outwards_with_unit_square_uvs() {
    let s = load_xml("<shape type=\"cube\"/>").unwrap();
    let m = &s.mesh;
    check_mesh(m, "cube");
    assert_eq!(m.positions.len(), 24);
    assert_eq!(m.triangle_count(), 12);
    assert!((total_area(m) - 24.0).abs() < 1e-4);
    let ns = m.normals.as_ref().unwrap();
    for t in 0..12 {
        let [a, b, c] = m.indices[t];
        let centroid = (m.positions[a as usize] + m.positions[b as usize] + m.positions[c as usize]) / 3.0;
        let ng = m.geometric_normal(t);
        // Outward, and along the axis of the centroid's largest coordinate.
        let axis = centroid.abs().max_element();
        assert!((ng.dot(centroid) - axis).abs() < 1e-5, "triangle {t}: {ng:?} {centroid:?}");
        assert!(ng.dot(centroid) > 0.0, "triangle {t} points inwards");
        assert_eq!(ns[a as usize], ng);
    }
    // Each face covers the whole unit square of uv space.
    let uvs = m.uvs.as_ref().unwrap();
    for face in 0..6 {
        let corners: Vec<Vec2> = uvs[face * 4..face * 4 + 4].to_vec();
        for want in [Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::ONE] {
            assert!(corners.contains(&want), "face {face}: {corners:?}");
        }
    }
    // flip_normals makes it an inward-facing box.
    let s = load_xml("<shape type=\"cube\"><boolean name=\"flip_normals\" value=\"true\"/></shape>").unwrap();
    check_mesh(&s.mesh, "flipped cube");
    let t0 = &s.mesh;
    let [a, b, c] = t0.indices[0];
    let centroid = (t0.positions[a as usize] + t0.positions[b as usize] + t0.positions[c as usize]) / 3.0;
    assert!(t0.geometric_normal(0).dot(centroid) < 0.0);
}

#[test]
fn disk_uv_is_polar() {
    let s = load_xml("<shape type=\"disk\"/>").unwrap();
    let m = &s.mesh;
    check_mesh(m, "disk");
    assert!((total_area(m) / PI - 1.0).abs() < 1e-3);
    for (p, uv) in m.positions.iter().zip(m.uvs.as_ref().unwrap()) {
        let r = p.truncate().length();
        assert!((uv.x - r).abs() < 1e-5);
        if r > 0.5 {
            let mut phi = p.y.atan2(p.x);
            if phi < 0.0 {
                phi += 2.0 * PI;
            }
            let dv = (uv.y - phi / (2.0 * PI)).abs();
            assert!(dv < 1e-4 || (dv - 1.0).abs() < 1e-4, "{p:?} {uv:?}");
        }
    }
}

#[test]
fn obj_uvs_flip_by_default_and_quads_fan() {
    let s = mesh_file("obj", "quad.obj", "").unwrap();
    let m = &s.mesh;
    check_mesh(m, "quad.obj");
    assert_eq!(m.triangle_count(), 2);
    assert_eq!(m.name, "quad.obj");
    let uvs = m.uvs.as_ref().unwrap();
    // vt 1 0.75 belongs to vertex (1, 1): flipped to v = 0.25 by default.
    let k = m.positions.iter().position(|p| *p == Vec3::new(1.0, 1.0, 0.0)).unwrap();
    assert!((uvs[k] - Vec2::new(1.0, 0.25)).length() < 1e-6, "{:?}", uvs[k]);
    let s = mesh_file("obj", "quad.obj", "<boolean name=\"flip_tex_coords\" value=\"false\"/>").unwrap();
    let k = s.mesh.positions.iter().position(|p| *p == Vec3::new(1.0, 1.0, 0.0)).unwrap();
    assert!((s.mesh.uvs.as_ref().unwrap()[k] - Vec2::new(1.0, 0.75)).length() < 1e-6);
    // The file's normals are kept; face_normals drops them.
    assert!(m.normals.is_some());
    let s = mesh_file("obj", "quad.obj", "<boolean name=\"face_normals\" value=\"true\"/>").unwrap();
    assert!(s.mesh.normals.is_none());
}

#[test]
fn obj_without_normals_gets_smooth_outward_normals() {
    let s = mesh_file("obj", "tetra_no_normals.obj", "").unwrap();
    let m = &s.mesh;
    check_mesh(m, "tetra");
    for (p, n) in m.positions.iter().zip(m.normals.as_ref().unwrap()) {
        assert!((p.normalize() - *n).length() < 1e-5);
    }
}

#[test]
fn mirrored_mesh_keeps_geometric_and_shading_normals_together() {
    let s =
        mesh_file("obj", "quad.obj", "<transform name=\"to_world\"><scale x=\"-1\"/></transform>").unwrap();
    let m = &s.mesh;
    check_mesh(m, "mirrored quad");
    assert!(m.normals.as_ref().unwrap().iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    // Non-uniform scale: normals use the inverse transpose and stay unit length.
    let s = load_xml(
        "<shape type=\"sphere\"><transform name=\"to_world\"><scale x=\"3\" y=\"1\" z=\"-0.5\"/></transform></shape>",
    )
    .unwrap();
    check_mesh(&s.mesh, "squashed mirrored sphere");
    for (p, n) in s.mesh.positions.iter().zip(s.mesh.normals.as_ref().unwrap()) {
        // The outward normal of the ellipsoid x²/9 + y² + z²/0.25 = 1 is ∝ (x/9, y, z/0.25).
        let g = Vec3::new(p.x / 9.0, p.y, p.z / 0.25).normalize();
        assert!((g - *n).length() < 1e-3, "{p:?}: {n:?} vs {g:?}");
    }
}

#[test]
fn ply_ascii_quads_fan_st_uvs_and_rewinding() {
    let s = mesh_file("ply", "quad_ascii.ply", "").unwrap();
    let m = &s.mesh;
    check_mesh(m, "quad_ascii.ply");
    assert_eq!(m.triangle_count(), 3);
    assert!((total_area(m) - 1.5).abs() < 1e-6);
    // s/t are read as u/v and not flipped for PLY.
    let uvs = m.uvs.as_ref().unwrap();
    assert_eq!(uvs[2], Vec2::new(1.0, 1.0));
    assert_eq!(uvs[4], Vec2::new(0.5, 0.5));
    assert!(s.warnings.iter().any(|w| w.contains("re-wound 1 triangles")), "{:?}", s.warnings);
}

#[test]
fn ply_binary_both_endiannesses() {
    for file in ["square_le.ply", "square_be.ply"] {
        let s = mesh_file("ply", file, "").unwrap();
        let m = &s.mesh;
        check_mesh(m, file);
        assert_eq!(m.positions.len(), 4, "{file}");
        assert_eq!(m.triangle_count(), 2);
        assert!((total_area(m) - 1.0).abs() < 1e-6);
        // No normals in the file: smooth normals are computed (all +z for a flat square).
        assert!(m.normals.as_ref().unwrap().iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
        let uvs = m.uvs.as_ref().unwrap();
        for (p, uv) in m.positions.iter().zip(uvs) {
            assert_eq!(*uv, p.truncate(), "{file}");
        }
    }
}

#[test]
fn truncated_ply_is_a_clear_error() {
    for (file, declared, got) in [("truncated.ply", 8, 3), ("truncated_le.ply", 4, 2)] {
        let e = mesh_file("ply", file, "").unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains(file), "{msg}");
        assert!(msg.contains("truncated"), "{msg}");
        assert!(
            msg.contains(&format!("declares {declared} 'vertex' elements"))
                && msg.contains(&format!("ends after {got}")),
            "{msg}"
        );
    }
    let e = mesh_file("ply", "bad_face_index.ply", "").unwrap_err();
    assert!(e.message.contains("face 0 refers to vertex 9"), "{e}");
}

#[test]
fn nan_vertex_obj_names_file_and_vertex() {
    let e = mesh_file("obj", "nan_vertex.obj", "").unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("nan_vertex.obj") && msg.contains("vertex 3") && msg.contains("line 4"), "{msg}");
}

#[test]
fn degenerate_triangles_are_skipped_with_a_warning() {
    let s = mesh_file("obj", "degenerate.obj", "").unwrap();
    assert_eq!(s.mesh.triangle_count(), 2);
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("skipped 2 degenerate triangles") && w.contains("degenerate.obj")),
        "{:?}",
        s.warnings
    );
    check_mesh(&s.mesh, "degenerate.obj");
    let e = mesh_file("obj", "all_degenerate.obj", "").unwrap_err();
    assert!(e.message.contains("no usable triangles"), "{e}");
}

#[test]
fn bad_obj_indices_error() {
    let e = mesh_file("obj", "bad_index.obj", "").unwrap_err();
    assert!(e.to_string().contains("bad_index.obj"), "{e}");
    assert!(e.message.contains("line 4 refers to vertex 7, but 3 are defined"), "{e}");
    // A relative index reaching above the first texture coordinate: tobj's index arithmetic would
    // overflow on it (a fuzzing find), so the loader refuses it first, naming the line.
    let e = mesh_file("obj", "bad_relative_index.obj", "").unwrap_err();
    assert!(e.message.contains("line 5 refers to texture coordinate -3, but 1 is defined above it"), "{e}");
}

#[test]
fn missing_mesh_file_names_path_and_shape_line() {
    let e = mesh_file("obj", "nope/missing.obj", "").unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("missing.obj") && msg.contains("not found"), "{msg}");
    // The <shape> element is on line 2 of the inline scene.
    assert_eq!(e.loc.line, 2, "{msg}");
    assert!(e.element.as_deref().unwrap().contains("<shape type=\"obj\">"));
}

#[test]
fn shape_parameters_are_checked() {
    let e = load_xml("<shape type=\"rectangle\"><float name=\"radius\" value=\"2\"/></shape>").unwrap_err();
    assert!(e.message.contains("unknown parameter 'radius'"), "{e}");
    let e = load_xml("<shape type=\"sphere\"><float name=\"radius\" value=\"-1\"/></shape>").unwrap_err();
    assert!(e.message.contains("radius"), "{e}");
    let e =
        load_xml("<shape type=\"cube\"><transform name=\"to_world\"><scale x=\"0\"/></transform></shape>")
            .unwrap_err();
    assert!(e.message.contains("singular"), "{e}");
    // Direct Props (as a plugin factory would build them) work too.
    let mut p = Props::new("shape", "disk", SrcLoc::builtin());
    p.set("to_world", PropValue::Transform(Mat4::from_translation(Vec3::Z)), SrcLoc::builtin());
    let s = load_shape(&p, Path::new(".")).unwrap();
    assert!(s.mesh.positions.iter().all(|q| (q.z - 1.0).abs() < 1e-6));
    assert_eq!(s.mesh.name, "disk");
}
