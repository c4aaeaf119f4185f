//! Wavefront OBJ loading through `tobj`: polygons are fanned into triangles and each distinct
//! (position, uv, normal) corner becomes one vertex, as Mitsuba's OBJ loader does.

use super::RawMesh;
use crate::scene::{Props, SceneError};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;

pub(super) fn load(path: &Path, props: &Props) -> Result<RawMesh, SceneError> {
    let bytes = std::fs::read(path)
        .map_err(|e| props.error(format!("cannot read mesh file '{}': {e}", path.display())))?;
    crate::resources::note_input_file(path);
    let text = String::from_utf8_lossy(&bytes);
    check_vertex_lines(&text, path, props)?;

    let options =
        tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    // Materials are irrelevant here (BSDFs come from the scene), so `mtllib` is never opened.
    let (models, _materials) =
        tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| Err(tobj::LoadError::GenericFailure))
            .map_err(|e| props.error(format!("cannot parse OBJ file '{}': {e}", path.display())))?;

    let all_uv = models
        .iter()
        .all(|m| !m.mesh.texcoords.is_empty() && m.mesh.texcoord_indices.len() == m.mesh.indices.len());
    let all_n = models
        .iter()
        .all(|m| !m.mesh.normals.is_empty() && m.mesh.normal_indices.len() == m.mesh.indices.len());

    let mut out = RawMesh { normals: all_n.then(Vec::new), uvs: all_uv.then(Vec::new), ..Default::default() };
    for model in &models {
        let mesh = &model.mesh;
        let mut corner_to_vertex: HashMap<(u32, u32, u32), u32> = HashMap::new();
        let fetch3 = |data: &[f32], i: u32, what: &str| -> Result<Vec3, SceneError> {
            let k = i as usize * 3;
            data.get(k..k + 3).map(|s| Vec3::new(s[0], s[1], s[2])).ok_or_else(|| {
                props.error(format!(
                    "OBJ file '{}': face refers to {what} {} which does not exist",
                    path.display(),
                    i + 1
                ))
            })
        };
        let mut corners = Vec::with_capacity(mesh.indices.len());
        for (c, &vi) in mesh.indices.iter().enumerate() {
            let ti = if all_uv { mesh.texcoord_indices[c] } else { 0 };
            let ni = if all_n { mesh.normal_indices[c] } else { 0 };
            let key = (vi, ti, ni);
            let id = match corner_to_vertex.get(&key) {
                Some(&id) => id,
                None => {
                    let id = out.positions.len() as u32;
                    out.positions.push(fetch3(&mesh.positions, vi, "vertex")?);
                    if let Some(ns) = &mut out.normals {
                        ns.push(fetch3(&mesh.normals, ni, "normal")?);
                    }
                    if let Some(uvs) = &mut out.uvs {
                        let k = ti as usize * 2;
                        let uv = mesh.texcoords.get(k..k + 2).ok_or_else(|| {
                            props.error(format!(
                                "OBJ file '{}': face refers to texture coordinate {} which does not exist",
                                path.display(),
                                ti + 1
                            ))
                        })?;
                        uvs.push(Vec2::new(uv[0], uv[1]));
                    }
                    corner_to_vertex.insert(key, id);
                    id
                }
            };
            corners.push(id);
        }
        if corners.len() % 3 != 0 {
            return Err(props.error(format!(
                "OBJ file '{}': object '{}' did not triangulate cleanly",
                path.display(),
                model.name
            )));
        }
        out.indices.extend(corners.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
    }
    if out.indices.is_empty() {
        return Err(props.error(format!("OBJ file '{}' contains no faces", path.display())));
    }
    Ok(out)
}

/// Checks what `tobj` takes on trust: vertex coordinates must be finite, and every index of a face
/// must name an element of its kind (position, texture coordinate, normal) that exists — a relative
/// (negative) index one defined above it. tobj turns such indices into `usize` arithmetic that
/// overflows (a panic in debug builds, found by fuzzing) or wraps to a valid-looking index.
fn check_vertex_lines(text: &str, path: &Path, props: &Props) -> Result<(), SceneError> {
    const KINDS: [(&str, &str); 3] = [("v", "vertex"), ("vt", "texture coordinate"), ("vn", "normal")];
    let keyword = |line: &str| line.split_whitespace().next().map(str::to_string);
    let mut totals = [0i64; 3];
    for line in text.lines() {
        if let Some(k) = keyword(line).and_then(|w| KINDS.iter().position(|(tag, _)| *tag == w)) {
            totals[k] += 1;
        }
    }
    let mut seen = [0i64; 3];
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let Some(word) = words.next() else { continue };
        if let Some(k) = KINDS.iter().position(|(tag, _)| *tag == word) {
            if k == 0 {
                for tok in words.clone().take(3) {
                    if let Ok(x) = tok.parse::<f64>() {
                        if !x.is_finite() {
                            return Err(props.error(format!(
                                "OBJ file '{}': vertex {} (line {}) has a non-finite coordinate '{tok}'",
                                path.display(),
                                seen[0],
                                line_no + 1
                            )));
                        }
                    }
                }
            }
            seen[k] += 1;
        } else if word == "f" {
            for corner in words {
                for (k, part) in corner.split('/').enumerate().take(3) {
                    let Ok(index) = part.parse::<i64>() else { continue };
                    let known = if index < 0 { seen[k] } else { totals[k] };
                    if index == 0 || index.unsigned_abs() > known as u64 {
                        return Err(props.error(format!(
                            "OBJ file '{}': the face on line {} refers to {} {index}, but {} {} defined{}",
                            path.display(),
                            line_no + 1,
                            KINDS[k].1,
                            known,
                            if known == 1 { "is" } else { "are" },
                            if index < 0 { " above it" } else { "" }
                        )));
                    }
                }
            }
        }
    }
    Ok(())
}
