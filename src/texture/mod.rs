//! Textures for BSDF and emitter parameters, as Mitsuba 3's texture plugins: constants, `bitmap`
//! (bilinear/nearest lookups with repeat/mirror/clamp wrapping) and the procedural `checkerboard`.
//! Image files are loaded through `crate::image` only when a scene has a bitmap, and once per file.

mod bitmap;
mod checkerboard;

pub use bitmap::{BitmapData, BitmapTexture, FilterType, WrapMode};
pub use checkerboard::Checkerboard;

use crate::props::{PropValue, Props, SceneError};
use crate::spectrum::{luminance, Spectrum};
use glam::{Mat4, Vec2, Vec3};
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(Clone, Debug)]
pub enum Texture {
    Constant(Spectrum),
    Bitmap(Arc<BitmapTexture>),
    Checkerboard(Arc<Checkerboard>),
}

impl Texture {
    pub fn eval(&self, uv: Vec2) -> Spectrum {
        match self {
            Texture::Constant(c) => *c,
            Texture::Bitmap(b) => b.eval(uv),
            Texture::Checkerboard(c) => c.eval(uv),
        }
    }

    /// Scalar value (for roughness-like parameters): the channel value of a monochrome source,
    /// the luminance of a colour one (as Mitsuba's `eval_1`).
    pub fn eval_1(&self, uv: Vec2) -> f32 {
        match self {
            Texture::Constant(c) => scalar_of(*c),
            Texture::Bitmap(b) => b.eval_1(uv),
            Texture::Checkerboard(c) => c.eval_1(uv),
        }
    }

    /// Mean value over the texture's domain (used for light power estimates and albedo guesses).
    pub fn mean(&self) -> Spectrum {
        match self {
            Texture::Constant(c) => *c,
            Texture::Bitmap(b) => b.mean(),
            Texture::Checkerboard(c) => c.mean(),
        }
    }

    /// Scalar mean as Mitsuba 3 reports it (channel average of a constant colour, mean luminance of a
    /// bitmap); BSDFs use it for lobe-selection weights so they sample as Mitsuba does.
    pub fn mean_scalar(&self) -> f32 {
        match self {
            Texture::Constant(c) => (c.x + c.y + c.z) / 3.0,
            Texture::Bitmap(b) => b.mean_luminance(),
            Texture::Checkerboard(c) => 0.5 * (c.color0.mean_scalar() + c.color1.mean_scalar()),
        }
    }

    /// True if the value does not depend on uv.
    pub fn is_constant(&self) -> bool {
        matches!(self, Texture::Constant(_))
    }

    /// Largest channel value anywhere (bounds for validation and sampling heuristics).
    pub fn max_value(&self) -> f32 {
        match self {
            Texture::Constant(c) => c.max_element(),
            Texture::Bitmap(b) => b.data.max_value,
            Texture::Checkerboard(c) => c.color0.max_value().max(c.color1.max_value()),
        }
    }

    /// Smallest scalar (`eval_1`) value anywhere.
    pub fn min_value_1(&self) -> f32 {
        match self {
            Texture::Constant(c) => scalar_of(*c),
            Texture::Bitmap(b) => b.data.min_value_1,
            Texture::Checkerboard(c) => c.color0.min_value_1().min(c.color1.min_value_1()),
        }
    }

    /// Reads parameter `name` as a colour or a nested texture; `default` when absent. Relative bitmap
    /// file names resolve against the directory of the scene file the element came from.
    pub fn from_param(props: &Props, name: &str, default: Spectrum) -> Result<Texture, SceneError> {
        let base = scene_dir(props);
        Texture::from_param_in(props, name, default, &base)
    }

    /// As [`Texture::from_param`], resolving relative file names against `base_dir`.
    pub fn from_param_in(
        props: &Props,
        name: &str,
        default: Spectrum,
        base_dir: &Path,
    ) -> Result<Texture, SceneError> {
        match props.get(name).map(|p| &p.value) {
            None => Ok(Texture::Constant(default)),
            Some(PropValue::Object(o)) => {
                if o.tag != "texture" {
                    return Err(props.error_at(
                        name,
                        format!("parameter '{name}' is a <{}>, expected a colour or a <texture>", o.tag),
                    ));
                }
                Texture::from_props(o, base_dir)
            }
            Some(_) => Ok(Texture::Constant(props.rgb(name, default)?)),
        }
    }

    /// Builds a texture from its `<texture type="...">` element.
    pub fn from_props(props: &Props, base_dir: &Path) -> Result<Texture, SceneError> {
        match props.plugin_type.as_str() {
            "bitmap" => Ok(Texture::Bitmap(Arc::new(BitmapTexture::from_props(props, base_dir)?))),
            "checkerboard" => Ok(Texture::Checkerboard(Arc::new(Checkerboard::from_props(props, base_dir)?))),
            // Mitsuba 3's constant-valued texture plugins.
            "uniform" => {
                props.expect_only(&["value"], &[])?;
                Ok(Texture::Constant(Vec3::splat(props.float("value", 1.0)?)))
            }
            "srgb" | "rgb" => {
                props.expect_only(&["color", "value"], &[])?;
                let c = match props.rgb_opt("color")? {
                    Some(c) => c,
                    None => props.rgb("value", Vec3::splat(0.5))?,
                };
                Ok(Texture::Constant(c))
            }
            other => Err(props.error(format!(
                "unsupported texture type '{other}' (supported: bitmap, checkerboard, uniform, srgb)"
            ))),
        }
    }
}

fn scalar_of(c: Spectrum) -> f32 {
    if c.x == c.y && c.y == c.z {
        c.x
    } else {
        luminance(c)
    }
}

/// The directory of the file an element was read from (the current directory for built-ins).
fn scene_dir(props: &Props) -> PathBuf {
    if props.loc.line == 0 && props.loc.file.to_string_lossy().starts_with('<') {
        return PathBuf::from(".");
    }
    props.loc.file.parent().map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."))
}

/// Applies a Mitsuba `to_uv` transform (given as 4×4) to a uv pair: the 2×2 linear block plus the
/// translation column, as Mitsuba 3's `Transform4f::extract()` reduces it to 3×3.
pub fn apply_to_uv(m: &Mat4, uv: Vec2) -> Vec2 {
    let p = m.transform_point3(Vec3::new(uv.x, uv.y, 0.0));
    Vec2::new(p.x, p.y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::props::SrcLoc;

    fn loc(line: u32) -> SrcLoc {
        SrcLoc::new(Path::new("/tmp/scene.xml"), line, 1)
    }

    #[test]
    fn constants_and_nested() {
        let mut p = Props::new("bsdf", "diffuse", loc(1));
        assert_eq!(
            Texture::from_param(&p, "reflectance", Vec3::splat(0.5)).unwrap().eval(Vec2::ZERO),
            Vec3::splat(0.5)
        );
        p.set("reflectance", PropValue::Rgb(Vec3::new(0.1, 0.2, 0.3)), loc(2));
        let t = Texture::from_param(&p, "reflectance", Vec3::splat(0.5)).unwrap();
        assert!(t.is_constant());
        assert_eq!(t.eval(Vec2::new(0.3, 0.9)), Vec3::new(0.1, 0.2, 0.3));

        let mut c = Props::new("texture", "checkerboard", loc(3));
        c.set("color0", PropValue::Rgb(Vec3::ONE), loc(4));
        p.set("reflectance", PropValue::Object(Arc::new(c)), loc(3));
        let t = Texture::from_param(&p, "reflectance", Vec3::splat(0.5)).unwrap();
        assert!(!t.is_constant());
        assert_eq!(t.eval(Vec2::new(0.25, 0.25)), Vec3::ONE);
        assert_eq!(t.eval(Vec2::new(0.75, 0.25)), Vec3::splat(0.2));
        assert!((t.mean() - Vec3::splat(0.6)).abs().max_element() < 1e-6);

        let bad = Props::new("texture", "perlin", loc(7));
        p.set("reflectance", PropValue::Object(Arc::new(bad)), loc(7));
        let e = Texture::from_param(&p, "reflectance", Vec3::ONE).unwrap_err();
        assert!(e.to_string().contains("unsupported texture type 'perlin'"), "{e}");
        assert_eq!(e.loc.line, 7);
    }

    #[test]
    fn missing_bitmap_file_is_a_located_error() {
        let mut b = Props::new("texture", "bitmap", loc(5));
        b.set("filename", PropValue::String("does_not_exist.png".into()), loc(6));
        let e = Texture::from_props(&b, Path::new("/nonexistent")).unwrap_err();
        assert_eq!(e.loc.line, 5);
        assert!(e.to_string().contains("does_not_exist.png"), "{e}");
    }
}
