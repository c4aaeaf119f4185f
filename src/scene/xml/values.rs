//! Property values of the scene XML: `<float>`, `<rgb>`, `<point>`, `<transform>` and the rest, read
//! from an element's attributes into `PropValue`s with Mitsuba 3's spellings, defaults and transform
//! composition (each operation left-multiplies, in f64 until the whole transform is rounded).

use super::{check_attrs, no_children, Attrs, XmlParser};
use crate::props::{PropValue, SceneError};
use glam::{DMat3, DMat4, DVec3, Mat4, Vec3};
use roxmltree::Node;

/// The transform being accumulated inside a `<transform>` element (f64 for exact composition).
pub(super) struct TransformAcc(pub(super) DMat4);

impl<'i> XmlParser<'i> {
    pub(super) fn parse_property(
        &self,
        node: Node<'_, 'i>,
        tag: &str,
        attrs: &Attrs,
    ) -> Result<PropValue, SceneError> {
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

    fn parse_transform_op(&self, node: Node<'_, 'i>, acc: &mut TransformAcc) -> Result<(), SceneError> {
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
