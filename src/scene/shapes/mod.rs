//! Shape plugins: OBJ/PLY meshes and tessellated analytic shapes (rectangle, cube, disk, sphere),
//! turned into world-space triangle meshes with Mitsuba 3's parameterisations (uv conventions of
//! `src/shapes/*.cpp`) and winding made consistent with the shading normals.

mod analytic;
mod obj;
mod ply;

pub use analytic::{sphere_resolution, SPHERE_PHI_SEGMENTS, SPHERE_THETA_RINGS};

use crate::geometry::{Transform, TriangleMesh, Vec2, Vec3};
use crate::scene::{Props, SceneError};
use std::path::{Path, PathBuf};

/// A shape turned into world-space triangles, with any warnings (e.g. skipped degenerate triangles).
#[derive(Debug, Default)]
pub struct LoadedShape {
    pub mesh: TriangleMesh,
    pub warnings: Vec<String>,
}

/// Loads the geometry of a `<shape>` element; relative file names resolve against `base_dir`.
pub fn load_shape(props: &Props, base_dir: &Path) -> Result<LoadedShape, SceneError> {
    const COMMON: [&str; 2] = ["to_world", "flip_normals"];
    const NESTED: [&str; 2] = ["bsdf", "emitter"];
    let known = |extra: &[&'static str]| -> Vec<&'static str> {
        COMMON.iter().chain(extra.iter()).copied().collect()
    };
    let (raw, source, smooth_if_missing) = match props.plugin_type.as_str() {
        "obj" | "ply" => {
            let is_obj = props.plugin_type == "obj";
            props.expect_only(&known(&["filename", "face_normals", "flip_tex_coords"]), &NESTED)?;
            let path = mesh_path(props, base_dir)?;
            let face_normals = props.bool("face_normals", false)?;
            // Mitsuba 3 flips v for OBJ by default (obj.cpp: `flip_tex_coords` defaults to true,
            // "for consistency with the Mitsuba 1 behavior"), but not for PLY (ply.cpp: false).
            let flip_tex_coords = props.bool("flip_tex_coords", is_obj)?;
            let raw = if is_obj { obj::load(&path, props)? } else { ply::load(&path, props)? };
            let mut raw = raw;
            if face_normals {
                raw.normals = None;
            }
            if flip_tex_coords {
                if let Some(uvs) = &mut raw.uvs {
                    for uv in uvs.iter_mut() {
                        uv.y = 1.0 - uv.y;
                    }
                }
            }
            // Mitsuba recomputes smooth vertex normals when a mesh has none and face normals
            // were not requested.
            (raw, path.display().to_string(), !face_normals)
        }
        "rectangle" => {
            props.expect_only(&known(&[]), &NESTED)?;
            (analytic::rectangle(), "rectangle".to_string(), false)
        }
        "cube" => {
            props.expect_only(&known(&[]), &NESTED)?;
            (analytic::cube(), "cube".to_string(), false)
        }
        "disk" => {
            props.expect_only(&known(&[]), &NESTED)?;
            (analytic::disk(), "disk".to_string(), false)
        }
        "sphere" => {
            props.expect_only(&known(&["center", "radius"]), &NESTED)?;
            let radius = props.float("radius", 1.0)?;
            if !(radius.is_finite() && radius > 0.0) {
                return Err(props.error_at("radius", format!("sphere radius must be positive, got {radius}")));
            }
            (analytic::sphere(), "sphere".to_string(), false)
        }
        other => {
            return Err(props.error(format!(
                "unsupported shape type '{other}' (supported: obj, ply, rectangle, cube, disk, sphere)"
            )))
        }
    };

    let mut to_world = props.transform("to_world")?;
    if props.plugin_type == "sphere" {
        let center = props.point_opt("center")?.unwrap_or(Vec3::ZERO);
        let radius = props.float("radius", 1.0)?;
        to_world =
            to_world * glam::Mat4::from_translation(center) * glam::Mat4::from_scale(Vec3::splat(radius));
    }
    let transform = Transform::new(to_world)
        .ok_or_else(|| props.error_at("to_world", "to_world is singular or not finite"))?;
    let flip_normals = props.bool("flip_normals", false)?;
    let name = props.id.clone().unwrap_or_else(|| match props.plugin_type.as_str() {
        "obj" | "ply" => Path::new(&source)
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_else(|| source.clone()),
        t => t.to_string(),
    });
    finalize(raw, &transform, flip_normals, smooth_if_missing, name, &source, props)
}

fn mesh_path(props: &Props, base_dir: &Path) -> Result<PathBuf, SceneError> {
    let filename =
        props.string_opt("filename")?.ok_or_else(|| props.error("missing parameter 'filename'"))?;
    let p = Path::new(&filename);
    let path = if p.is_absolute() { p.to_path_buf() } else { base_dir.join(p) };
    if !path.is_file() {
        return Err(props.error(format!("mesh file '{}' not found", path.display())));
    }
    Ok(path)
}

/// Object-space geometry straight from a loader, before validation and transformation.
#[derive(Debug, Default)]
pub(crate) struct RawMesh {
    pub positions: Vec<Vec3>,
    pub normals: Option<Vec<Vec3>>,
    pub uvs: Option<Vec<Vec2>>,
    /// Triangles (polygons already fanned) in the file's winding.
    pub indices: Vec<[u32; 3]>,
}

/// Validates, transforms to world space, fixes winding, drops degenerate triangles.
fn finalize(
    raw: RawMesh,
    transform: &Transform,
    flip_normals: bool,
    smooth_if_missing: bool,
    name: String,
    source: &str,
    props: &Props,
) -> Result<LoadedShape, SceneError> {
    let RawMesh { positions, normals, uvs, indices } = raw;
    let n = positions.len();
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(props.error(format!("{source}: vertex {i} has a non-finite position {:?}", positions[i])));
    }
    if let Some(ns) = &normals {
        if ns.len() != n {
            return Err(props.error(format!("{source}: {} normals for {n} vertices", ns.len())));
        }
    }
    if let Some(uv) = &uvs {
        if uv.len() != n {
            return Err(props.error(format!("{source}: {} texture coordinates for {n} vertices", uv.len())));
        }
    }
    if let Some((t, tri)) = indices.iter().enumerate().find(|(_, tri)| tri.iter().any(|&i| i as usize >= n)) {
        return Err(props.error(format!(
            "{source}: triangle {t} refers to vertex {:?} but the mesh has only {n} vertices",
            tri
        )));
    }

    let world_pos: Vec<Vec3> = positions.iter().map(|&p| transform.point(p)).collect();
    if let Some(i) = world_pos.iter().position(|p| !p.is_finite()) {
        return Err(props.error(format!("{source}: vertex {i} is not finite after to_world")));
    }
    let mut world_normals: Option<Vec<Vec3>> =
        normals.map(|ns| ns.iter().map(|&v| transform.normal(v).normalize_or_zero()).collect());

    let mut warnings = Vec::new();
    // A handedness-flipping transform reverses the winding; restore it so the geometric normal
    // stays on the side that the inverse-transpose-transformed shading normals point to.
    let mirror = transform.flips_handedness();
    let mut tris = Vec::with_capacity(indices.len());
    let mut degenerate = 0usize;
    let mut rewound = 0usize;
    for &[a, b, c] in &indices {
        let (a, b, c) = if mirror { (a, c, b) } else { (a, b, c) };
        let (pa, pb, pc) = (world_pos[a as usize], world_pos[b as usize], world_pos[c as usize]);
        let cross = (pb - pa).cross(pc - pa);
        let len = cross.length();
        let scale = (pb - pa).length_squared().max((pc - pa).length_squared());
        if !(len.is_finite() && len > scale * 1e-12 && len > 0.0) {
            degenerate += 1;
            continue;
        }
        let mut tri = [a, b, c];
        if let Some(ns) = &world_normals {
            let avg = ns[a as usize] + ns[b as usize] + ns[c as usize];
            if avg.dot(cross) < 0.0 {
                tri = [a, c, b];
                rewound += 1;
            }
        }
        tris.push(tri);
    }
    if degenerate > 0 {
        warnings.push(format!("skipped {degenerate} degenerate triangles in {source}"));
    }
    if rewound > 0 {
        warnings.push(format!(
            "re-wound {rewound} triangles of {source} whose winding disagreed with their vertex normals"
        ));
    }
    if tris.is_empty() {
        return Err(props.error(format!(
            "{source}: the mesh has no usable triangles ({} in the file, {degenerate} degenerate)",
            indices.len()
        )));
    }

    let need_smooth = match &world_normals {
        None => smooth_if_missing,
        Some(ns) => ns.contains(&Vec3::ZERO),
    };
    if need_smooth {
        let smooth = angle_weighted_normals(&world_pos, &tris);
        match &mut world_normals {
            Some(ns) => {
                // Repair only the zero-length normals (e.g. "vn 0 0 0" in the file).
                for (v, s) in ns.iter_mut().zip(&smooth) {
                    if *v == Vec3::ZERO {
                        *v = *s;
                    }
                }
            }
            None => world_normals = Some(smooth),
        }
        if let Some(ns) = &mut world_normals {
            // Vertices used by no triangle keep a zero normal; give them any unit vector.
            for v in ns.iter_mut() {
                if *v == Vec3::ZERO || !v.is_finite() {
                    *v = Vec3::Z;
                }
            }
        }
    }

    if flip_normals {
        for t in &mut tris {
            t.swap(1, 2);
        }
        if let Some(ns) = &mut world_normals {
            for v in ns.iter_mut() {
                *v = -*v;
            }
        }
    }

    Ok(LoadedShape {
        mesh: TriangleMesh { name, positions: world_pos, normals: world_normals, uvs, indices: tris },
        warnings,
    })
}

/// Vertex normals weighted by the corner angle of each incident triangle (Thürmer & Wüthrich,
/// "Computing Vertex Normals from Polygonal Facets", JGT 1998), the scheme Mitsuba uses when a mesh
/// has no normals.
fn angle_weighted_normals(pos: &[Vec3], tris: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; pos.len()];
    for tri in tris {
        let face = {
            let [a, b, c] = tri.map(|i| pos[i as usize]);
            (b - a).cross(c - a).normalize_or_zero()
        };
        for k in 0..3 {
            let v = pos[tri[k] as usize];
            let e1 = (pos[tri[(k + 1) % 3] as usize] - v).normalize_or_zero();
            let e2 = (pos[tri[(k + 2) % 3] as usize] - v).normalize_or_zero();
            let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
            if angle.is_finite() {
                acc[tri[k] as usize] += face * angle;
            }
        }
    }
    acc.into_iter().map(|v| v.normalize_or_zero()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{PropValue, SrcLoc};

    fn props(t: &str) -> Props {
        Props::new("shape", t, SrcLoc::new(Path::new("t.xml"), 7, 3))
    }

    #[test]
    fn mirrored_rectangle_keeps_normals_and_winding_together() {
        let mut p = props("rectangle");
        p.set(
            "to_world",
            PropValue::Transform(glam::Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0))),
            SrcLoc::builtin(),
        );
        let s = load_shape(&p, Path::new(".")).unwrap();
        let ns = s.mesh.normals.as_ref().unwrap();
        for t in 0..s.mesh.triangle_count() {
            let ng = s.mesh.geometric_normal(t);
            assert!((ng - Vec3::Z).length() < 1e-6, "{ng:?}");
            for &i in &s.mesh.indices[t] {
                assert!(ns[i as usize].dot(ng) > 0.99);
            }
        }
    }

    #[test]
    fn flip_normals_flips_both() {
        let mut p = props("rectangle");
        p.set("flip_normals", PropValue::Bool(true), SrcLoc::builtin());
        let s = load_shape(&p, Path::new(".")).unwrap();
        assert!((s.mesh.geometric_normal(0) + Vec3::Z).length() < 1e-6);
        assert!(s.mesh.normals.unwrap().iter().all(|n| (*n + Vec3::Z).length() < 1e-6));
    }

    #[test]
    fn unknown_parameter_and_type_are_errors() {
        let mut p = props("cube");
        p.set("radius", PropValue::Float(1.0), SrcLoc::builtin());
        let e = load_shape(&p, Path::new(".")).unwrap_err();
        assert!(e.message.contains("unknown parameter 'radius'"), "{e}");
        let e = load_shape(&props("serialized"), Path::new(".")).unwrap_err();
        assert!(e.message.contains("unsupported shape type 'serialized'"), "{e}");
    }

    #[test]
    fn smooth_normals_of_a_tetrahedron_point_outwards() {
        let pos = vec![
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, -1.0, -1.0),
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(-1.0, -1.0, 1.0),
        ];
        let tris = [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]];
        let ns = angle_weighted_normals(&pos, &tris);
        for (p, n) in pos.iter().zip(&ns) {
            assert!((p.normalize() - *n).length() < 1e-5, "{p:?} {n:?}");
        }
    }
}
