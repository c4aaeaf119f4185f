//! Mitsuba XML scene parser: reads the scene format of Mitsuba 3 (and the 0.6/2.x spellings it
//! upgrades in memory) into plugin `Props`, following Mitsuba 3's `src/core/xml.cpp` semantics for
//! `<default>`/`$name` substitution, `<ref>`, and transform composition (each op left-multiplies).
//! This file walks the element tree (plugins, ids and references, defaults); `values` reads one
//! property's value or transform.

use super::{PropValue, Props, SceneError, SrcLoc};
use document::{check_parse_fits, parse_document, LineIndex, PARSE_BYTES_PER_FILE_BYTE};
use roxmltree::Node;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod document;
mod values;

pub use document::{MAX_INCLUDE_DEPTH, MAX_NESTING};
pub use values::{look_at, mat4_from_rows, rotation};

/// Parses a scene file into a root `Props` (tag `scene`) whose entries are the top-level plugins in
/// document order; `defines` are `-D name=value` overrides of `<default>` parameters.
pub fn parse_file(path: &Path, defines: &[(String, String)]) -> Result<Props, SceneError> {
    if let Ok(meta) = std::fs::metadata(path) {
        // The text itself is held too.
        check_parse_fits(meta.len(), PARSE_BYTES_PER_FILE_BYTE + 1, path)?;
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| SceneError::file(path, format!("cannot read scene file: {e}")))?;
    parse_str(&text, path, defines)
}

/// Parses scene XML held in memory; `path` is only used for messages (and is what `loc.file` holds).
pub fn parse_str(text: &str, path: &Path, defines: &[(String, String)]) -> Result<Props, SceneError> {
    let doc = parse_document(text, path)?;
    // The chain of files being parsed, for <include> cycles (canonical where the file exists).
    let includes = vec![(path.canonicalize().unwrap_or_else(|_| path.to_path_buf()), path.to_path_buf())];
    let mut parser = XmlParser {
        lines: LineIndex::new(text),
        base_loc: SrcLoc::new(path, 0, 0),
        params: defines.to_vec(),
        ids: HashMap::new(),
        includes,
    };
    parser.parse_root(doc.root_element())
}

fn at(base: &SrcLoc, line: u32, col: u32) -> SrcLoc {
    SrcLoc { file: base.file.clone(), line, col }
}

/// Plugin element tags we understand (each becomes a nested `Props`).
const PLUGIN_TAGS: &[&str] =
    &["bsdf", "texture", "emitter", "rfilter", "sampler", "film", "shape", "sensor", "integrator"];

/// Tags Mitsuba knows but this renderer deliberately does not support.
const UNSUPPORTED_PLUGIN_TAGS: &[(&str, &str)] = &[
    ("medium", "participating media are not supported"),
    ("phase", "phase functions (participating media) are not supported"),
    ("volume", "volume data (participating media) are not supported"),
    ("subsurface", "subsurface scattering is not supported"),
];

struct XmlParser<'i> {
    lines: LineIndex<'i>,
    base_loc: SrcLoc,
    /// `-D` defines first, then `<default>`s in document order: the first entry for a name wins,
    /// so command-line values override defaults (as in Mitsuba).
    params: Vec<(String, String)>,
    ids: HashMap<String, (Arc<Props>, SrcLoc)>,
    /// Files being parsed, outermost first: the scene, then each `<include>` on the way here (the
    /// canonical path, which identifies a file, and the path as named, for messages).
    includes: Vec<(PathBuf, PathBuf)>,
}

/// One element's attributes after `$name` substitution.
struct Attrs<'a> {
    list: Vec<(&'a str, String)>,
}

impl Attrs<'_> {
    fn get(&self, name: &str) -> Option<&str> {
        self.list.iter().find(|(n, _)| *n == name).map(|(_, v)| v.as_str())
    }
}

impl<'i> XmlParser<'i> {
    fn loc_of(&self, node: Node) -> SrcLoc {
        let (line, col) = self.lines.line_and_column(node.range().start);
        at(&self.base_loc, line, col)
    }

    fn err(&self, node: Node, message: impl Into<String>) -> SceneError {
        SceneError::new(self.loc_of(node), Some(describe_node(node)), message)
    }

    fn parse_root(&mut self, root: Node<'_, 'i>) -> Result<Props, SceneError> {
        self.check_scene_root(root)?;
        let mut scene = Props::new("scene", "", self.loc_of(root));
        for child in root.children() {
            self.parse_child(child, &mut scene, None, true)?;
        }
        Ok(scene)
    }

    /// A scene file's root (the scene's own, or an included file's) is `<scene version=...>`.
    fn check_scene_root(&self, root: Node<'_, 'i>) -> Result<(), SceneError> {
        let tag = root.tag_name().name();
        if tag != "scene" {
            return Err(self.err(root, format!("the root element must be <scene>, found <{tag}>")));
        }
        let attrs = self.attrs(root)?;
        check_attrs(self, root, &attrs, &["version"])?;
        let version = match attrs.get("version") {
            Some(v) => v.to_string(),
            None => {
                return Err(self.err(
                    root,
                    "missing 'version' attribute (Mitsuba requires e.g. <scene version=\"3.0.0\">)",
                ))
            }
        };
        parse_version(&version).ok_or_else(|| {
            self.err(
                root,
                format!(
                    "unsupported scene version '{version}' (expected major.minor.patch with major 0, 2 or 3)"
                ),
            )
        })?;
        Ok(())
    }

    /// Collects attributes, substituting `$name` parameters in every value.
    fn attrs<'n>(&self, node: Node<'n, 'i>) -> Result<Attrs<'n>, SceneError> {
        let mut list = Vec::new();
        for a in node.attributes() {
            let v = self.substitute(node, a.value())?;
            list.push((a.name(), v));
        }
        Ok(Attrs { list })
    }

    fn substitute(&self, node: Node, value: &str) -> Result<String, SceneError> {
        if !value.contains('$') {
            return Ok(value.to_string());
        }
        let mut out = String::with_capacity(value.len());
        let mut rest = value;
        while let Some(pos) = rest.find('$') {
            out.push_str(&rest[..pos]);
            let after = &rest[pos + 1..];
            // Longest defined name that prefixes the text after '$' (Mitsuba replaces the longest
            // names first, so `$spp` never eats the start of `$spp_max`).
            let best = self
                .params
                .iter()
                .filter(|(n, _)| !n.is_empty() && after.starts_with(n.as_str()))
                .max_by_key(|(n, _)| n.len());
            match best {
                Some((n, v)) => {
                    out.push_str(v);
                    rest = &after[n.len()..];
                }
                None => {
                    let ident: String =
                        after.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                    let shown = if ident.is_empty() { "" } else { &ident };
                    return Err(self.err(
                        node,
                        format!(
                            "undefined parameter '${shown}' in \"{value}\": add <default name=\"{shown}\" value=\"...\"/> to the scene or pass -D {shown}=value"
                        ),
                    ));
                }
            }
        }
        out.push_str(rest);
        Ok(out)
    }

    /// Parses one child node of a plugin (or of the scene) into `parent`.
    fn parse_child(
        &mut self,
        node: Node<'_, 'i>,
        parent: &mut Props,
        parent_plugin_type: Option<&str>,
        top_level: bool,
    ) -> Result<(), SceneError> {
        if node.is_comment() || node.is_pi() {
            return Ok(());
        }
        if node.is_text() {
            let t = node.text().unwrap_or("");
            if t.trim().is_empty() {
                return Ok(());
            }
            return Err(SceneError::new(
                self.loc_of(node),
                None,
                format!("unexpected text \"{}\" (only elements are allowed here)", t.trim()),
            ));
        }
        if !node.is_element() {
            return Ok(());
        }
        let tag = node.tag_name().name();
        let loc = self.loc_of(node);
        let attrs = self.attrs(node)?;

        if PLUGIN_TAGS.contains(&tag) {
            let (name, obj) = self.parse_plugin(node, tag, &attrs)?;
            let name = if top_level { String::new() } else { name };
            self.set_unique(node, parent, &name, PropValue::Object(obj), loc)?;
            return Ok(());
        }
        if let Some((_, why)) = UNSUPPORTED_PLUGIN_TAGS.iter().find(|(t, _)| *t == tag) {
            return Err(self.err(node, format!("<{tag}> is not supported: {why}")));
        }

        match tag {
            "default" => {
                check_attrs(self, node, &attrs, &["name", "value"])?;
                let name = self.required(node, &attrs, "name")?;
                let value = self.required(node, &attrs, "value")?;
                if name.is_empty() {
                    return Err(self.err(node, "<default> needs a non-empty 'name'"));
                }
                if !self.params.iter().any(|(n, _)| n == name) {
                    self.params.push((name.to_string(), value.to_string()));
                }
                no_children(self, node)?;
                Ok(())
            }
            "ref" => {
                check_attrs(self, node, &attrs, &["id", "name"])?;
                let id = self.required(node, &attrs, "id")?;
                let (obj, _) = self.ids.get(id).ok_or_else(|| {
                    self.err(
                        node,
                        format!("reference to unknown id '{id}' (ids must be declared before they are referenced)"),
                    )
                })?;
                let obj = obj.clone();
                let name = if top_level {
                    String::new()
                } else {
                    attrs.get("name").map(snake_case).unwrap_or_default()
                };
                no_children(self, node)?;
                self.set_unique(node, parent, &name, PropValue::Object(obj), loc)
            }
            "alias" => {
                check_attrs(self, node, &attrs, &["id", "as"])?;
                let id = self.required(node, &attrs, "id")?.to_string();
                let alias = self.required(node, &attrs, "as")?.to_string();
                let target = self
                    .ids
                    .get(&id)
                    .ok_or_else(|| self.err(node, format!("<alias> of unknown id '{id}'")))?
                    .0
                    .clone();
                self.declare_id(node, &alias, target, loc)
            }
            "include" => {
                check_attrs(self, node, &attrs, &["filename"])?;
                let filename = self.required(node, &attrs, "filename")?.to_string();
                no_children(self, node)?;
                self.include(node, &filename, parent, parent_plugin_type, top_level)
            }
            "path" => Err(self.err(
                node,
                "<path> is not supported: file names resolve relative to the scene file",
            )),
            "scene" => Err(self.err(node, "<scene> cannot be nested")),
            "float" | "integer" | "boolean" | "string" | "rgb" | "srgb" | "spectrum" | "point"
            | "vector" | "blackbody" | "transform" => {
                let raw_name = self.required(node, &attrs, "name")?;
                let mut name = snake_case(raw_name);
                // Mitsuba 0.6's `diffuseReflectance` of the diffuse BSDF became `reflectance`.
                if parent.tag == "bsdf"
                    && parent_plugin_type == Some("diffuse")
                    && name == "diffuse_reflectance"
                {
                    name = "reflectance".into();
                }
                let value = self.parse_property(node, tag, &attrs)?;
                self.set_unique(node, parent, &name, value, loc)
            }
            "matrix" | "translate" | "scale" | "rotate" | "lookat" | "lookAt" => Err(self.err(
                node,
                format!("<{tag}> may only appear inside a <transform>"),
            )),
            _ => Err(self.err(
                node,
                format!(
                    "unknown element <{tag}> (expected a plugin such as <shape>, <bsdf>, <emitter>, or a property such as <float>, <rgb>, <transform>, <ref>)"
                ),
            )),
        }
    }

    fn required<'a>(&self, node: Node, attrs: &'a Attrs, name: &str) -> Result<&'a str, SceneError> {
        attrs.get(name).ok_or_else(|| self.err(node, format!("missing attribute '{name}'")))
    }

    fn set_unique(
        &self,
        node: Node,
        parent: &mut Props,
        name: &str,
        value: PropValue,
        loc: SrcLoc,
    ) -> Result<(), SceneError> {
        if !name.is_empty() {
            if let Some(prev) = parent.get(name) {
                return Err(self.err(
                    node,
                    format!("parameter '{name}' is given twice (first at line {})", prev.loc.line),
                ));
            }
        }
        parent.set(name, value, loc);
        Ok(())
    }

    fn declare_id(&mut self, node: Node, id: &str, obj: Arc<Props>, loc: SrcLoc) -> Result<(), SceneError> {
        if let Some((_, prev)) = self.ids.get(id) {
            return Err(self.err(node, format!("duplicate id '{id}' (first declared at line {})", prev.line)));
        }
        self.ids.insert(id.to_string(), (obj, loc));
        Ok(())
    }

    /// Parses a plugin element; returns its parameter name (possibly empty) and the shared object.
    fn parse_plugin(
        &mut self,
        node: Node<'_, 'i>,
        tag: &str,
        attrs: &Attrs,
    ) -> Result<(String, Arc<Props>), SceneError> {
        check_attrs(self, node, attrs, &["type", "id", "name"])?;
        let plugin_type = attrs.get("type").ok_or_else(|| {
            self.err(node, format!("<{tag}> needs a 'type' attribute (e.g. <{tag} type=\"...\">)"))
        })?;
        if plugin_type.is_empty() {
            return Err(self.err(node, format!("<{tag}> has an empty 'type'")));
        }
        let plugin_type = upgrade_plugin_type(tag, plugin_type).map_err(|msg| self.err(node, msg))?;
        let loc = self.loc_of(node);
        let mut props = Props::new(tag, &plugin_type, loc.clone());
        if let Some(id) = attrs.get("id") {
            if let Some((_, prev)) = self.ids.get(id) {
                return Err(
                    self.err(node, format!("duplicate id '{id}' (first declared at line {})", prev.line))
                );
            }
            props.id = Some(id.to_string());
        }
        for child in node.children() {
            self.parse_child(child, &mut props, Some(&plugin_type), false)?;
        }
        let obj = Arc::new(props);
        if let Some(id) = &obj.id {
            self.declare_id(node, &id.clone(), obj.clone(), loc)?;
        }
        let name = attrs.get("name").map(snake_case).unwrap_or_default();
        Ok((name, obj))
    }
}

fn check_attrs(p: &XmlParser, node: Node, attrs: &Attrs, allowed: &[&str]) -> Result<(), SceneError> {
    for (name, _) in &attrs.list {
        if !allowed.contains(name) {
            return Err(p.err(
                node,
                format!(
                    "unexpected attribute '{name}' on <{}> (allowed: {})",
                    node.tag_name().name(),
                    allowed.join(", ")
                ),
            ));
        }
    }
    Ok(())
}

fn no_children(p: &XmlParser, node: Node) -> Result<(), SceneError> {
    for c in node.children() {
        if c.is_element() {
            return Err(
                p.err(c, format!("<{}> cannot contain <{}>", node.tag_name().name(), c.tag_name().name()))
            );
        }
        if c.is_text() && !c.text().unwrap_or("").trim().is_empty() {
            return Err(p.err(node, "unexpected text content"));
        }
    }
    Ok(())
}

/// How an element is named in messages: `<float name="fov">`, `<shape type="obj" id="Floor">`.
fn describe_node(node: Node) -> String {
    let mut s = format!("<{}", node.tag_name().name());
    for key in ["type", "id", "name"] {
        if let Some(v) = node.attribute(key) {
            s.push_str(&format!(" {key}=\"{v}\""));
        }
    }
    s.push('>');
    s
}

fn parse_version(v: &str) -> Option<(u32, u32, u32)> {
    let parts: Vec<&str> = v.trim().split('.').collect();
    if parts.len() != 3 {
        return None;
    }
    let n: Vec<u32> = parts.iter().map(|p| p.parse().ok()).collect::<Option<_>>()?;
    if !matches!(n[0], 0..=3) {
        return None;
    }
    Some((n[0], n[1], n[2]))
}

/// Maps plugin names that Mitsuba 0.6 used and Mitsuba 3 dropped.
fn upgrade_plugin_type(tag: &str, t: &str) -> Result<String, String> {
    match (tag, t) {
        ("film", "ldrfilm") => Err(
            "Mitsuba 0.6's 'ldrfilm' does not exist in Mitsuba 3: use <film type=\"hdrfilm\"> (the output format follows the output file name)"
                .into(),
        ),
        _ => Ok(t.to_string()),
    }
}

/// Mitsuba 3's camelCase → snake_case upgrade: an underscore goes before each lower→upper step and
/// the following run of capitals is lowercased, so `intIOR` → `int_ior`, `toWorld` → `to_world`.
/// Names that are already snake_case come back unchanged.
pub fn snake_case(name: &str) -> String {
    let chars: Vec<char> = name.chars().collect();
    let mut out = String::with_capacity(name.len() + 4);
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        out.push(c);
        if (c.is_ascii_lowercase() || c.is_ascii_digit())
            && i + 1 < chars.len()
            && chars[i + 1].is_ascii_uppercase()
        {
            out.push('_');
            i += 1;
            while i < chars.len() && chars[i].is_ascii_uppercase() {
                out.push(chars[i].to_ascii_lowercase());
                i += 1;
            }
            continue;
        }
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn snake_case_matches_mitsuba_upgrade() {
        for (a, b) in [
            ("toWorld", "to_world"),
            ("maxDepth", "max_depth"),
            ("intIOR", "int_ior"),
            ("extIOR", "ext_ior"),
            ("specularReflectance", "specular_reflectance"),
            ("sampleCount", "sample_count"),
            ("fovAxis", "fov_axis"),
            ("faceNormals", "face_normals"),
            ("rrDepth", "rr_depth"),
            ("to_world", "to_world"),
            ("fov", "fov"),
            ("color0", "color0"),
        ] {
            assert_eq!(snake_case(a), b, "{a}");
        }
    }

    #[test]
    fn substitution_prefers_longest_name_and_reports_missing() {
        let text = r#"<scene version="3.0.0">
            <default name="s" value="1"/>
            <default name="spp" value="16"/>
            <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
            <integrator type="path"><integer name="max_depth" value="$s$s"/></integrator>
        </scene>"#;
        let p = parse_str(text, Path::new("t.xml"), &[]).unwrap();
        let objs: Vec<_> = p.objects().map(|(_, o)| o.clone()).collect();
        assert_eq!(objs[0].int("sample_count", 0).unwrap(), 16);
        assert_eq!(objs[1].int("max_depth", 0).unwrap(), 11);
    }

    #[test]
    fn lookat_columns_follow_mitsuba() {
        let m = look_at(DVec3::new(0.0, 0.0, 5.0), DVec3::ZERO, Some(DVec3::Y)).unwrap();
        // Camera looks down −z; left = up × dir = y × (−z) = −x.
        assert!((m.z_axis.truncate() - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-12);
        assert!((m.x_axis.truncate() - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-12);
        assert!((m.y_axis.truncate() - DVec3::Y).length() < 1e-12);
        assert!(look_at(DVec3::ZERO, DVec3::ZERO, None).is_none());
        assert!(look_at(DVec3::ZERO, DVec3::Y, Some(DVec3::Y)).is_none());
    }
}
