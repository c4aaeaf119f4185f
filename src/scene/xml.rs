//! Mitsuba XML scene parser: reads the scene format of Mitsuba 3 (and the 0.6/2.x spellings it
//! upgrades in memory) into plugin `Props`, following Mitsuba 3's `src/core/xml.cpp` semantics for
//! `<default>`/`$name` substitution, `<ref>`, and transform composition (each op left-multiplies).

use super::{PropValue, Props, SceneError, SrcLoc};
use glam::{DMat3, DMat4, DVec3, Mat4, Vec3};
use roxmltree::{Document, Node};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// Parses a scene file into a root `Props` (tag `scene`) whose entries are the top-level plugins in
/// document order; `defines` are `-D name=value` overrides of `<default>` parameters.
pub fn parse_file(path: &Path, defines: &[(String, String)]) -> Result<Props, SceneError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SceneError::file(path, format!("cannot read scene file: {e}")))?;
    parse_str(&text, path, defines)
}

/// Parses scene XML held in memory; `path` is only used for messages (and is what `loc.file` holds).
pub fn parse_str(text: &str, path: &Path, defines: &[(String, String)]) -> Result<Props, SceneError> {
    let base_loc = SrcLoc::new(path, 0, 0);
    // roxmltree refuses DTDs (and therefore entity expansion) by default, which is what we want.
    let doc = Document::parse(text).map_err(|e| {
        let pos = e.pos();
        SceneError::new(at(&base_loc, pos.row, pos.col), None, format!("malformed XML: {e}"))
    })?;
    let mut parser = XmlParser { doc: &doc, base_loc, params: defines.to_vec(), ids: HashMap::new() };
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

struct XmlParser<'d, 'i> {
    doc: &'d Document<'i>,
    base_loc: SrcLoc,
    /// `-D` defines first, then `<default>`s in document order: the first entry for a name wins,
    /// so command-line values override defaults (as in Mitsuba).
    params: Vec<(String, String)>,
    ids: HashMap<String, (Arc<Props>, SrcLoc)>,
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

/// The transform being accumulated inside a `<transform>` element (f64 for exact composition).
struct TransformAcc(DMat4);

impl<'d, 'i> XmlParser<'d, 'i> {
    fn loc_of(&self, node: Node) -> SrcLoc {
        let pos = self.doc.text_pos_at(node.range().start);
        at(&self.base_loc, pos.row, pos.col)
    }

    fn err(&self, node: Node, message: impl Into<String>) -> SceneError {
        SceneError::new(self.loc_of(node), Some(describe_node(node)), message)
    }

    fn parse_root(&mut self, root: Node<'d, 'i>) -> Result<Props, SceneError> {
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
        let mut scene = Props::new("scene", "", self.loc_of(root));
        for child in root.children() {
            self.parse_child(child, &mut scene, None, true)?;
        }
        Ok(scene)
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
        node: Node<'d, 'i>,
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
            "include" => Err(self.err(
                node,
                "<include> is not supported: merge the included file into the scene",
            )),
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
        node: Node<'d, 'i>,
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

    fn parse_property(&self, node: Node<'d, 'i>, tag: &str, attrs: &Attrs) -> Result<PropValue, SceneError> {
        match tag {
            "float" => {
                check_attrs(self, node, attrs, &["name", "value"])?;
                no_children(self, node)?;
                let v = self.required(node, attrs, "value")?;
                Ok(PropValue::Float(self.number(node, "value", v)?))
            }
            "integer" => {
                check_attrs(self, node, attrs, &["name", "value"])?;
                no_children(self, node)?;
                let v = self.required(node, attrs, "value")?;
                let i = v.trim().parse::<i64>().map_err(|_| {
                    self.err(node, format!("attribute 'value' must be an integer, got \"{v}\""))
                })?;
                Ok(PropValue::Int(i))
            }
            "boolean" => {
                check_attrs(self, node, attrs, &["name", "value"])?;
                no_children(self, node)?;
                let v = self.required(node, attrs, "value")?;
                match v.trim().to_ascii_lowercase().as_str() {
                    "true" => Ok(PropValue::Bool(true)),
                    "false" => Ok(PropValue::Bool(false)),
                    _ => Err(self
                        .err(node, format!("attribute 'value' must be \"true\" or \"false\", got \"{v}\""))),
                }
            }
            "string" => {
                check_attrs(self, node, attrs, &["name", "value"])?;
                no_children(self, node)?;
                Ok(PropValue::String(self.required(node, attrs, "value")?.to_string()))
            }
            "rgb" | "srgb" => {
                check_attrs(self, node, attrs, &["name", "value", "intent"])?;
                no_children(self, node)?;
                let v = self.required(node, attrs, "value")?;
                let (rgb, is_hex) = self.color(node, v)?;
                // Mitsuba 0.6's <srgb> and hex colours are gamma-encoded sRGB; store linear.
                let rgb = if tag == "srgb" || is_hex { rgb.map(srgb_to_linear) } else { rgb };
                Ok(PropValue::Rgb(rgb))
            }
            "spectrum" => {
                check_attrs(self, node, attrs, &["name", "value", "filename", "intent"])?;
                no_children(self, node)?;
                if attrs.get("filename").is_some() {
                    return Err(self.err(
                        node,
                        "spectra from files are not supported: RGB rendering supports uniform spectra only (use <rgb>)",
                    ));
                }
                let v = self.required(node, attrs, "value")?;
                let tokens = tokens(v);
                if tokens.len() == 1 && !tokens[0].contains(':') {
                    let x = self.number(node, "value", tokens[0])? as f32;
                    Ok(PropValue::Rgb(Vec3::splat(x)))
                } else {
                    Err(self.err(
                        node,
                        format!(
                            "spectrum \"{v}\" is not uniform: RGB rendering supports uniform spectra only (a single value); convert it to <rgb>"
                        ),
                    ))
                }
            }
            "blackbody" => {
                Err(self.err(node, "<blackbody> is not supported in RGB rendering; convert it to <rgb>"))
            }
            "point" | "vector" => {
                check_attrs(self, node, attrs, &["name", "value", "x", "y", "z"])?;
                no_children(self, node)?;
                let v = self.xyz(node, attrs, 0.0)?;
                let v = v.as_vec3();
                Ok(if tag == "point" { PropValue::Point(v) } else { PropValue::Vector(v) })
            }
            "transform" => {
                check_attrs(self, node, attrs, &["name"])?;
                let mut acc = TransformAcc(DMat4::IDENTITY);
                for child in node.children() {
                    self.parse_transform_op(child, &mut acc)?;
                }
                let m = acc.0;
                if !m.is_finite() {
                    return Err(self.err(node, "transform is not finite"));
                }
                Ok(PropValue::Transform(m.as_mat4()))
            }
            _ => unreachable!("parse_property called with <{tag}>"),
        }
    }

    fn parse_transform_op(&self, node: Node<'d, 'i>, acc: &mut TransformAcc) -> Result<(), SceneError> {
        if node.is_comment() || node.is_pi() {
            return Ok(());
        }
        if node.is_text() {
            if node.text().unwrap_or("").trim().is_empty() {
                return Ok(());
            }
            return Err(SceneError::new(self.loc_of(node), None, "unexpected text inside <transform>"));
        }
        if !node.is_element() {
            return Ok(());
        }
        let tag = node.tag_name().name();
        let attrs = self.attrs(node)?;
        no_children(self, node)?;
        let op = match tag {
            "matrix" => {
                check_attrs(self, node, &attrs, &["value"])?;
                let v = self.required(node, &attrs, "value")?;
                let vals = self.numbers(node, "value", v)?;
                match vals.len() {
                    16 => DMat4::from_cols_array(&vals.try_into().unwrap()).transpose(),
                    9 => DMat4::from_mat3(
                        DMat3::from_cols_array(&vals.try_into().unwrap()).transpose(),
                    ),
                    n => {
                        return Err(self.err(
                            node,
                            format!("<matrix> needs 16 values (row-major 4x4) or 9 (3x3), got {n}"),
                        ))
                    }
                }
            }
            "translate" => {
                check_attrs(self, node, &attrs, &["value", "x", "y", "z"])?;
                DMat4::from_translation(self.xyz(node, &attrs, 0.0)?)
            }
            "scale" => {
                check_attrs(self, node, &attrs, &["value", "x", "y", "z"])?;
                DMat4::from_scale(self.xyz(node, &attrs, 1.0)?)
            }
            "rotate" => {
                check_attrs(self, node, &attrs, &["value", "x", "y", "z", "angle"])?;
                let axis = self.xyz(node, &attrs, 0.0)?;
                let angle = self.required(node, &attrs, "angle")?;
                let angle = self.number(node, "angle", angle)?;
                if axis.length_squared() == 0.0 {
                    return Err(self.err(node, "<rotate> needs a non-zero axis (x, y, z or value)"));
                }
                rotation(axis, angle)
            }
            "lookat" | "lookAt" => {
                check_attrs(self, node, &attrs, &["origin", "target", "up"])?;
                let origin = self.vec3_attr(node, &attrs, "origin")?;
                let target = self.vec3_attr(node, &attrs, "target")?;
                let up = match attrs.get("up") {
                    Some(_) => Some(self.vec3_attr(node, &attrs, "up")?),
                    None => None,
                };
                look_at(origin, target, up).ok_or_else(|| {
                    self.err(
                        node,
                        "invalid <lookat>: origin equals target, or 'up' is parallel to the viewing direction",
                    )
                })?
            }
            _ => {
                return Err(self.err(
                    node,
                    format!(
                        "<{tag}> cannot appear inside <transform> (expected matrix, translate, scale, rotate or lookat)"
                    ),
                ))
            }
        };
        acc.0 = op * acc.0;
        Ok(())
    }

    fn number(&self, node: Node, attr: &str, text: &str) -> Result<f64, SceneError> {
        parse_f64(text)
            .ok_or_else(|| self.err(node, format!("attribute '{attr}' must be a number, got \"{text}\"")))
    }

    fn numbers(&self, node: Node, attr: &str, text: &str) -> Result<Vec<f64>, SceneError> {
        tokens(text)
            .into_iter()
            .map(|t| {
                parse_f64(t).ok_or_else(|| {
                    self.err(
                        node,
                        format!("attribute '{attr}' must hold numbers, but \"{t}\" in \"{text}\" is not one"),
                    )
                })
            })
            .collect()
    }

    /// `x`/`y`/`z` attributes (missing ones take `default`) or `value` with one or three numbers.
    fn xyz(&self, node: Node, attrs: &Attrs, default: f64) -> Result<DVec3, SceneError> {
        if let Some(v) = attrs.get("value") {
            if attrs.get("x").is_some() || attrs.get("y").is_some() || attrs.get("z").is_some() {
                return Err(self.err(node, "give either 'value' or 'x'/'y'/'z', not both"));
            }
            let vals = self.numbers(node, "value", v)?;
            return match vals.len() {
                1 => Ok(DVec3::splat(vals[0])),
                3 => Ok(DVec3::new(vals[0], vals[1], vals[2])),
                n => {
                    Err(self.err(node, format!("attribute 'value' needs 1 or 3 numbers, got {n} in \"{v}\"")))
                }
            };
        }
        let mut out = DVec3::splat(default);
        for (i, axis) in ["x", "y", "z"].iter().enumerate() {
            if let Some(t) = attrs.get(axis) {
                out[i] = self.number(node, axis, t)?;
            }
        }
        Ok(out)
    }

    fn vec3_attr(&self, node: Node, attrs: &Attrs, name: &str) -> Result<DVec3, SceneError> {
        let text = self.required(node, attrs, name)?;
        let vals = self.numbers(node, name, text)?;
        if vals.len() != 3 {
            return Err(self
                .err(node, format!("attribute '{name}' needs 3 numbers, got {} in \"{text}\"", vals.len())));
        }
        Ok(DVec3::new(vals[0], vals[1], vals[2]))
    }

    /// An `<rgb>` value: "r, g, b", "r g b", a single grey value, or `#rrggbb` (returned flagged).
    fn color(&self, node: Node, text: &str) -> Result<(Vec3, bool), SceneError> {
        let t = text.trim();
        if let Some(hex) = t.strip_prefix('#') {
            let bad = || self.err(node, format!("invalid hex colour \"{text}\" (expected #rrggbb)"));
            if hex.len() != 6 || !hex.is_ascii() {
                return Err(bad());
            }
            let mut c = [0f32; 3];
            for (i, ch) in c.iter_mut().enumerate() {
                let byte = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
                *ch = byte as f32 / 255.0;
            }
            return Ok((Vec3::from(c), true));
        }
        let vals = self.numbers(node, "value", text)?;
        match vals.len() {
            1 => Ok((Vec3::splat(vals[0] as f32), false)),
            3 => Ok((Vec3::new(vals[0] as f32, vals[1] as f32, vals[2] as f32), false)),
            n => Err(self.err(node, format!("a colour needs 1 or 3 values, got {n} in \"{text}\""))),
        }
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

/// Splits on whitespace and commas, as Mitsuba's tokenizer does for lists of numbers.
fn tokens(s: &str) -> Vec<&str> {
    s.split(|c: char| c.is_whitespace() || c == ',').filter(|t| !t.is_empty()).collect()
}

fn parse_f64(s: &str) -> Option<f64> {
    let s = s.trim();
    let v: f64 = s.parse().ok()?;
    // Rust accepts "inf"/"nan" spellings; a scene number must be an actual finite value.
    v.is_finite().then_some(v)
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
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

/// Rotation by `angle_deg` degrees about `axis`, right-handed (counter-clockwise when looking
/// down the axis towards the origin), as Mitsuba's `Transform4f::rotate`.
pub fn rotation(axis: DVec3, angle_deg: f64) -> DMat4 {
    // In double precision, as Mitsuba 3's XML loader builds it before rounding the whole
    // transform to single precision: a quarter turn leaves cos = 6e-17, so a rotated floor stays
    // flat to 1e-16 (docs/rough-glass.md, "A face touching the floor").
    DMat4::from_axis_angle(axis.normalize(), angle_deg.to_radians())
}

/// Mitsuba's look-at camera-to-world matrix: columns `[left, new_up, dir, origin]` with
/// `dir = normalize(target − origin)`, `left = normalize(up × dir)`, `new_up = dir × left`.
/// Without `up`, Mitsuba picks any vector perpendicular to `dir`. `None` when degenerate.
pub fn look_at(origin: DVec3, target: DVec3, up: Option<DVec3>) -> Option<DMat4> {
    let dir = (target - origin).try_normalize()?;
    let up = match up {
        Some(u) if u.length_squared() > 0.0 => u,
        _ => dir.any_orthonormal_vector(),
    };
    let left = up.cross(dir).try_normalize()?;
    let new_up = dir.cross(left);
    let m = DMat4::from_cols(left.extend(0.0), new_up.extend(0.0), dir.extend(0.0), origin.extend(1.0));
    m.is_finite().then_some(m)
}

/// Convenience for tests and callers: a `Mat4` from 16 row-major values.
pub fn mat4_from_rows(v: [f32; 16]) -> Mat4 {
    Mat4::from_cols_array(&v).transpose()
}

#[cfg(test)]
mod tests {
    use super::*;

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
