//! Stanford PLY loading (ASCII and binary) through `ply-rs-bw`, reading elements one at a time so a
//! file shorter than its header promises gives a clear "truncated" error instead of a bare EOF.

use super::RawMesh;
use crate::scene::{Props, SceneError};
use glam::{Vec2, Vec3};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Encoding, PropertyAccess, PropertyAccessResult};
use std::io::{BufRead, BufReader, ErrorKind};
use std::path::Path;

/// Texture-coordinate property spellings accepted by Mitsuba, in its order of preference.
const UV_NAMES: [(&str, &str); 3] = [("u", "v"), ("texture_u", "texture_v"), ("s", "t")];

#[derive(Default)]
struct Vertex {
    p: [f64; 3],
    n: [f64; 3],
    /// One (u, v) slot per spelling in `UV_NAMES`; the loader picks the pair the header declares.
    uv: [[f64; 2]; 3],
}

impl Vertex {
    fn set(&mut self, name: &str, x: f64) -> PropertyAccessResult {
        let slot = match name {
            "x" => &mut self.p[0],
            "y" => &mut self.p[1],
            "z" => &mut self.p[2],
            "nx" => &mut self.n[0],
            "ny" => &mut self.n[1],
            "nz" => &mut self.n[2],
            _ => {
                let Some((k, c)) = UV_NAMES.iter().enumerate().find_map(|(k, (u, v))| {
                    (name == *u).then_some((k, 0)).or((name == *v).then_some((k, 1)))
                }) else {
                    return PropertyAccessResult::Ignored;
                };
                &mut self.uv[k][c]
            }
        };
        *slot = x;
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Vertex::default()
    }
    fn set_char(&mut self, n: &str, v: i8) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_uchar(&mut self, n: &str, v: u8) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_short(&mut self, n: &str, v: i16) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_ushort(&mut self, n: &str, v: u16) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_int(&mut self, n: &str, v: i32) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_uint(&mut self, n: &str, v: u32) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_float(&mut self, n: &str, v: f32) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_double(&mut self, n: &str, v: f64) -> PropertyAccessResult {
        self.set(n, v)
    }
}

#[derive(Default)]
struct Face {
    indices: Vec<i64>,
}

impl Face {
    fn set<T: Into<i64>>(&mut self, name: &str, v: Vec<T>) -> PropertyAccessResult {
        if name == "vertex_indices" || name == "vertex_index" {
            self.indices = v.into_iter().map(Into::into).collect();
            PropertyAccessResult::Set
        } else {
            PropertyAccessResult::Ignored
        }
    }
}

impl PropertyAccess for Face {
    fn new() -> Self {
        Face::default()
    }
    fn set_list_char(&mut self, n: &str, v: Vec<i8>) -> PropertyAccessResult {
        self.set(n, v)
    }
    fn set_list_uchar(&mut self, n: &str, v: Vec<u8>) -> PropertyAccessResult {
        self.set(n, v)
    }
    fn set_list_short(&mut self, n: &str, v: Vec<i16>) -> PropertyAccessResult {
        self.set(n, v)
    }
    fn set_list_ushort(&mut self, n: &str, v: Vec<u16>) -> PropertyAccessResult {
        self.set(n, v)
    }
    fn set_list_int(&mut self, n: &str, v: Vec<i32>) -> PropertyAccessResult {
        self.set(n, v)
    }
    fn set_list_uint(&mut self, n: &str, v: Vec<u32>) -> PropertyAccessResult {
        self.set(n, v)
    }
}

/// Elements we do not use (edges, materials...) are read and dropped.
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

pub(super) fn load(path: &Path, props: &Props) -> Result<RawMesh, SceneError> {
    let fail = |msg: String| props.error(format!("PLY file '{}': {msg}", path.display()));
    let file = std::fs::File::open(path).map_err(|e| fail(format!("cannot open: {e}")))?;
    crate::resources::note_input_file(path);
    let mut reader = Reader::new(BufReader::new(file));
    let header =
        Parser::<Skip>::new().read_header(&mut reader).map_err(|e| fail(format!("invalid header: {e}")))?;

    let vertex_def = header.elements.get("vertex").ok_or_else(|| fail("no 'vertex' element".into()))?;
    let has = |name: &str| vertex_def.properties.contains_key(name);
    for axis in ["x", "y", "z"] {
        if !has(axis) {
            return Err(fail(format!("vertex element has no '{axis}' property")));
        }
    }
    let has_normals = has("nx") && has("ny") && has("nz");
    let uv_pair = UV_NAMES.iter().position(|(u, v)| has(u) && has(v));
    let face_def = header.elements.get("face").ok_or_else(|| fail("no 'face' element".into()))?;
    if !face_def.properties.contains_key("vertex_indices")
        && !face_def.properties.contains_key("vertex_index")
    {
        return Err(fail("face element has no 'vertex_indices' (or 'vertex_index') list".into()));
    }

    let mut out = RawMesh {
        normals: has_normals.then(Vec::new),
        uvs: uv_pair.is_some().then(Vec::new),
        ..Default::default()
    };
    let encoding = header.encoding;
    let input = reader.get_mut();
    for (name, def) in &header.elements {
        match name.as_str() {
            "vertex" => {
                let pair = uv_pair.unwrap_or(0);
                read_elements::<Vertex, _>(input, encoding, def, path, props, |_, v| {
                    out.positions.push(Vec3::new(v.p[0] as f32, v.p[1] as f32, v.p[2] as f32));
                    if let Some(ns) = &mut out.normals {
                        ns.push(Vec3::new(v.n[0] as f32, v.n[1] as f32, v.n[2] as f32));
                    }
                    if let Some(uvs) = &mut out.uvs {
                        uvs.push(Vec2::new(v.uv[pair][0] as f32, v.uv[pair][1] as f32));
                    }
                    Ok(())
                })?;
            }
            "face" => {
                let n_vertices = vertex_def.count;
                read_elements::<Face, _>(input, encoding, def, path, props, |i, f| {
                    if f.indices.len() < 3 {
                        return Err(format!("face {i} has {} vertices (at least 3 needed)", f.indices.len()));
                    }
                    if let Some(&bad) = f.indices.iter().find(|&&k| k < 0 || k as usize >= n_vertices) {
                        return Err(format!(
                            "face {i} refers to vertex {bad}, but the file declares {n_vertices} vertices"
                        ));
                    }
                    // Polygons become fans around their first corner.
                    let idx: Vec<u32> = f.indices.iter().map(|&k| k as u32).collect();
                    for k in 1..idx.len() - 1 {
                        out.indices.push([idx[0], idx[k], idx[k + 1]]);
                    }
                    Ok(())
                })?;
            }
            _ => read_elements::<Skip, _>(input, encoding, def, path, props, |_, _| Ok(()))?,
        }
    }
    Ok(out)
}

/// Reads the `def.count` elements of one kind, handing each to `sink`.
fn read_elements<E: PropertyAccess, R: BufRead>(
    input: &mut R,
    encoding: Encoding,
    def: &ElementDef,
    path: &Path,
    props: &Props,
    mut sink: impl FnMut(usize, E) -> Result<(), String>,
) -> Result<(), SceneError> {
    let parser = Parser::<E>::new();
    let fail = |msg: String| props.error(format!("PLY file '{}': {msg}", path.display()));
    let truncated = |i: usize| {
        fail(format!(
            "truncated: the header declares {} '{}' elements, but the file ends after {i}",
            def.count, def.name
        ))
    };
    let mut line = String::new();
    for i in 0..def.count {
        let element = match encoding {
            Encoding::Ascii => loop {
                line.clear();
                let n = input.read_line(&mut line).map_err(|e| fail(format!("read error: {e}")))?;
                if n == 0 {
                    return Err(truncated(i));
                }
                if !line.trim().is_empty() {
                    break parser.read_ascii_element(&line, def);
                }
            },
            Encoding::BinaryLittleEndian => parser.read_little_endian_element(input, def),
            Encoding::BinaryBigEndian => parser.read_big_endian_element(input, def),
        };
        match element {
            Ok(e) => sink(i, e).map_err(fail)?,
            Err(e) if e.kind() == ErrorKind::UnexpectedEof => return Err(truncated(i)),
            Err(e) => return Err(fail(format!("cannot read '{}' element {i}: {e}", def.name))),
        }
    }
    Ok(())
}
