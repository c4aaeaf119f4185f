//! Plugin properties: the parsed parameters of one XML element, as Mitsuba's `Properties`, and the
//! errors that point at the element at fault. They sit below both the plugins (BSDFs, lights, sensor,
//! textures read them) and the scene loader (which fills them), as Mitsuba 3's `Properties` sits below
//! its plugins. The XML parser fills them (names already normalised to Mitsuba 3's snake_case); each
//! plugin's constructor reads what it understands and calls `expect_only` so misspelt parameters are errors.

pub mod error;

pub use error::{SceneError, SrcLoc};

use glam::{Mat4, Vec3};
use std::sync::Arc;

#[derive(Clone, Debug, PartialEq)]
pub enum PropValue {
    Float(f64),
    Int(i64),
    Bool(bool),
    String(String),
    /// `<rgb>`, or a `<spectrum>` given as a single uniform value.
    Rgb(Vec3),
    Point(Vec3),
    Vector(Vec3),
    Transform(Mat4),
    /// A nested plugin (`<bsdf>`, `<texture>`, `<emitter>`, `<rfilter>`, `<sampler>`, `<film>`,
    /// `<shape>`...) or a resolved `<ref>`.
    Object(Arc<Props>),
}

impl PropValue {
    pub fn kind(&self) -> &'static str {
        match self {
            PropValue::Float(_) => "float",
            PropValue::Int(_) => "integer",
            PropValue::Bool(_) => "boolean",
            PropValue::String(_) => "string",
            PropValue::Rgb(_) => "rgb",
            PropValue::Point(_) => "point",
            PropValue::Vector(_) => "vector",
            PropValue::Transform(_) => "transform",
            PropValue::Object(_) => "object",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Prop {
    /// Parameter name; nested objects without a `name` attribute get an empty name.
    pub name: String,
    pub value: PropValue,
    pub loc: SrcLoc,
}

/// The parameters of one plugin instance.
#[derive(Clone, Debug, PartialEq)]
pub struct Props {
    /// Element tag: `scene`, `shape`, `bsdf`, `emitter`, `sensor`, `film`, `rfilter`, `sampler`,
    /// `texture`, `integrator`.
    pub tag: String,
    /// The `type` attribute (`diffuse`, `obj`, ...); empty for `scene`.
    pub plugin_type: String,
    pub id: Option<String>,
    pub loc: SrcLoc,
    pub entries: Vec<Prop>,
}

impl Props {
    pub fn new(tag: &str, plugin_type: &str, loc: SrcLoc) -> Props {
        Props { tag: tag.into(), plugin_type: plugin_type.into(), id: None, loc, entries: Vec::new() }
    }

    /// Adds or replaces a named parameter (nested objects without a name are always appended).
    pub fn set(&mut self, name: &str, value: PropValue, loc: SrcLoc) {
        if !name.is_empty() {
            if let Some(p) = self.entries.iter_mut().find(|p| p.name == name) {
                p.value = value;
                p.loc = loc;
                return;
            }
        }
        self.entries.push(Prop { name: name.into(), value, loc });
    }

    /// How this element is named in messages: `<bsdf type="diffuse" id="Floor">`.
    pub fn describe(&self) -> String {
        match &self.id {
            Some(id) => format!("<{} type=\"{}\" id=\"{}\">", self.tag, self.plugin_type, id),
            None => format!("<{} type=\"{}\">", self.tag, self.plugin_type),
        }
    }

    /// An error located at this element.
    pub fn error(&self, message: impl Into<String>) -> SceneError {
        SceneError::new(self.loc.clone(), Some(self.describe()), message)
    }

    /// An error located at parameter `name` if present, else at the element.
    pub fn error_at(&self, name: &str, message: impl Into<String>) -> SceneError {
        let loc = self.get(name).map(|p| p.loc.clone()).unwrap_or_else(|| self.loc.clone());
        SceneError::new(loc, Some(self.describe()), message)
    }

    pub fn get(&self, name: &str) -> Option<&Prop> {
        self.entries.iter().find(|p| p.name == name)
    }

    pub fn has(&self, name: &str) -> bool {
        self.get(name).is_some()
    }

    fn wrong_type(&self, p: &Prop, expected: &str) -> SceneError {
        SceneError::new(
            p.loc.clone(),
            Some(self.describe()),
            format!("parameter '{}' is a {}, expected {}", p.name, p.value.kind(), expected),
        )
    }

    pub fn float_opt(&self, name: &str) -> Result<Option<f32>, SceneError> {
        match self.get(name) {
            None => Ok(None),
            Some(p) => match &p.value {
                PropValue::Float(v) => Ok(Some(*v as f32)),
                PropValue::Int(v) => Ok(Some(*v as f32)),
                _ => Err(self.wrong_type(p, "a float")),
            },
        }
    }

    pub fn float(&self, name: &str, default: f32) -> Result<f32, SceneError> {
        Ok(self.float_opt(name)?.unwrap_or(default))
    }

    pub fn int_opt(&self, name: &str) -> Result<Option<i64>, SceneError> {
        match self.get(name) {
            None => Ok(None),
            Some(p) => match &p.value {
                PropValue::Int(v) => Ok(Some(*v)),
                PropValue::Float(v) if v.fract() == 0.0 => Ok(Some(*v as i64)),
                _ => Err(self.wrong_type(p, "an integer")),
            },
        }
    }

    pub fn int(&self, name: &str, default: i64) -> Result<i64, SceneError> {
        Ok(self.int_opt(name)?.unwrap_or(default))
    }

    pub fn bool(&self, name: &str, default: bool) -> Result<bool, SceneError> {
        match self.get(name) {
            None => Ok(default),
            Some(p) => match &p.value {
                PropValue::Bool(v) => Ok(*v),
                _ => Err(self.wrong_type(p, "a boolean")),
            },
        }
    }

    pub fn string_opt(&self, name: &str) -> Result<Option<String>, SceneError> {
        match self.get(name) {
            None => Ok(None),
            Some(p) => match &p.value {
                PropValue::String(v) => Ok(Some(v.clone())),
                _ => Err(self.wrong_type(p, "a string")),
            },
        }
    }

    pub fn string(&self, name: &str, default: &str) -> Result<String, SceneError> {
        Ok(self.string_opt(name)?.unwrap_or_else(|| default.to_string()))
    }

    /// A colour: `<rgb>`, a uniform `<spectrum>`, or a plain float taken as grey.
    pub fn rgb_opt(&self, name: &str) -> Result<Option<Vec3>, SceneError> {
        match self.get(name) {
            None => Ok(None),
            Some(p) => match &p.value {
                PropValue::Rgb(v) => Ok(Some(*v)),
                PropValue::Float(v) => Ok(Some(Vec3::splat(*v as f32))),
                PropValue::Int(v) => Ok(Some(Vec3::splat(*v as f32))),
                _ => Err(self.wrong_type(p, "an rgb colour")),
            },
        }
    }

    pub fn rgb(&self, name: &str, default: Vec3) -> Result<Vec3, SceneError> {
        Ok(self.rgb_opt(name)?.unwrap_or(default))
    }

    pub fn point_opt(&self, name: &str) -> Result<Option<Vec3>, SceneError> {
        match self.get(name) {
            None => Ok(None),
            Some(p) => match &p.value {
                PropValue::Point(v) | PropValue::Vector(v) => Ok(Some(*v)),
                _ => Err(self.wrong_type(p, "a point")),
            },
        }
    }

    pub fn vector_opt(&self, name: &str) -> Result<Option<Vec3>, SceneError> {
        self.point_opt(name)
    }

    /// A transform; identity when absent.
    pub fn transform(&self, name: &str) -> Result<Mat4, SceneError> {
        match self.get(name) {
            None => Ok(Mat4::IDENTITY),
            Some(p) => match &p.value {
                PropValue::Transform(m) => Ok(*m),
                _ => Err(self.wrong_type(p, "a transform")),
            },
        }
    }

    /// A nested plugin by parameter name.
    pub fn object(&self, name: &str) -> Result<Option<&Arc<Props>>, SceneError> {
        match self.get(name) {
            None => Ok(None),
            Some(p) => match &p.value {
                PropValue::Object(o) => Ok(Some(o)),
                _ => Err(self.wrong_type(p, "a nested object")),
            },
        }
    }

    /// All nested plugins in document order, with their parameter names (possibly empty).
    pub fn objects(&self) -> impl Iterator<Item = (&str, &Arc<Props>)> {
        self.entries.iter().filter_map(|p| match &p.value {
            PropValue::Object(o) => Some((p.name.as_str(), o)),
            _ => None,
        })
    }

    /// Nested plugins with a given tag (e.g. all `bsdf` children).
    pub fn objects_with_tag<'a>(&'a self, tag: &'a str) -> impl Iterator<Item = &'a Arc<Props>> + 'a {
        self.objects().filter(move |(_, o)| o.tag == tag).map(|(_, o)| o)
    }

    /// Fails on any named parameter not in `known`, naming it and listing what this plugin accepts.
    /// Nested objects are checked by the tags in `known_tags` (e.g. `["bsdf"]` for `twosided`).
    pub fn expect_only(&self, known: &[&str], known_tags: &[&str]) -> Result<(), SceneError> {
        for p in &self.entries {
            if let PropValue::Object(o) = &p.value {
                let named_ok = !p.name.is_empty() && known.contains(&p.name.as_str());
                if !named_ok && !known_tags.contains(&o.tag.as_str()) {
                    return Err(SceneError::new(
                        p.loc.clone(),
                        Some(self.describe()),
                        format!("unexpected nested <{}> element", o.tag),
                    ));
                }
                continue;
            }
            if !known.contains(&p.name.as_str()) {
                let list = if known.is_empty() { "none".to_string() } else { known.join(", ") };
                return Err(SceneError::new(
                    p.loc.clone(),
                    Some(self.describe()),
                    format!("unknown parameter '{}' (this plugin accepts: {})", p.name, list),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn loc(line: u32) -> SrcLoc {
        SrcLoc::new(Path::new("s.xml"), line, 1)
    }

    #[test]
    fn typed_access_and_errors_name_the_place() {
        let mut p = Props::new("bsdf", "roughconductor", loc(3));
        p.set("alpha", PropValue::Float(0.1), loc(4));
        p.set("distribution", PropValue::String("ggx".into()), loc(5));
        p.set("eta", PropValue::Rgb(Vec3::new(1.0, 2.0, 3.0)), loc(6));
        assert_eq!(p.float("alpha", 0.5).unwrap(), 0.1);
        assert_eq!(p.float("missing", 0.5).unwrap(), 0.5);
        assert_eq!(p.string("distribution", "beckmann").unwrap(), "ggx");
        let e = p.float("distribution", 0.0).unwrap_err();
        assert_eq!(e.loc.line, 5);
        assert!(e.to_string().contains("expected a float"), "{e}");
        let e = p.expect_only(&["alpha", "distribution"], &[]).unwrap_err();
        assert!(e.to_string().contains("unknown parameter 'eta'"), "{e}");
        assert!(e.to_string().starts_with("s.xml:6:1"), "{e}");
        p.expect_only(&["alpha", "distribution", "eta"], &[]).unwrap();
    }
}
