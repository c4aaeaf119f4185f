//! `bitmap`: an image texture, as Mitsuba 3's `bitmap` plugin.
//!
//! | Parameter     | Type      | Default    | Meaning                                                      |
//! |---------------|-----------|------------|--------------------------------------------------------------|
//! | `filename`    | string    | (required) | image file, relative to the scene file                       |
//! | `filter_type` | string    | `bilinear` | `bilinear` interpolation or `nearest` texel lookup           |
//! | `wrap_mode`   | string    | `repeat`   | outside [0,1]: `repeat`, `mirror` or `clamp`                 |
//! | `raw`         | boolean   | `false`    | keep stored values (no sRGB → linear conversion)             |
//! | `to_uv`       | transform | identity   | applied to uv before the lookup (2×2 block + translation)    |
//!
//! Orientation, as Mitsuba 3: uv (0,0) is the top-left corner of the image's first stored row, v grows
//! downwards through the rows; texel centres sit at ((x+½)/W, (y+½)/H). Mitsuba's mesh loaders flip
//! v on load (OBJ/PLY `flip_tex_coords`, default true), which is what makes OBJ's bottom-left-origin
//! uvs come out upright. RGBA drops alpha, Y/YA become monochrome.

use super::apply_to_uv;
use crate::image::ImageBuf;
use crate::props::{Props, SceneError};
use crate::spectrum::{luminance, Spectrum};
use glam::{Mat4, Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock, Weak};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterType {
    Nearest,
    Bilinear,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WrapMode {
    Repeat,
    Mirror,
    Clamp,
}

/// Pixel data shared by every texture that uses the same file.
#[derive(Debug)]
pub struct BitmapData {
    pub width: usize,
    pub height: usize,
    /// 1 (monochrome) or 3 (RGB).
    pub channels: usize,
    pub pixels: Vec<f32>,
    pub mean: Spectrum,
    pub mean_luminance: f32,
    pub max_value: f32,
    pub min_value_1: f32,
}

impl BitmapData {
    /// Converts a decoded image (1–4 channels, linear values) into texture storage.
    pub fn from_image(img: &ImageBuf) -> Result<BitmapData, String> {
        if img.width == 0 || img.height == 0 {
            return Err("the image is empty".into());
        }
        let channels = match img.channels {
            1 | 2 => 1,
            3 | 4 => 3,
            c => return Err(format!("unsupported channel count {c} (expected 1 to 4)")),
        };
        if img.data.len() < img.width * img.height * img.channels {
            return Err("the image buffer is shorter than its dimensions".into());
        }
        let n = img.width * img.height;
        let mut pixels = Vec::with_capacity(n * channels);
        let mut sum = glam::DVec3::ZERO;
        let mut sum_lum = 0.0f64;
        let mut max_value = f32::NEG_INFINITY;
        let mut min_value_1 = f32::INFINITY;
        for i in 0..n {
            let src = &img.data[i * img.channels..(i + 1) * img.channels];
            let v = if channels == 1 {
                Vec3::splat(sanitize(src[0]))
            } else {
                Vec3::new(sanitize(src[0]), sanitize(src[1]), sanitize(src[2]))
            };
            if channels == 1 {
                pixels.push(v.x);
            } else {
                pixels.extend_from_slice(&[v.x, v.y, v.z]);
            }
            let scalar = if channels == 1 { v.x } else { luminance(v) };
            sum += v.as_dvec3();
            sum_lum += scalar as f64;
            max_value = max_value.max(v.max_element());
            min_value_1 = min_value_1.min(scalar);
        }
        Ok(BitmapData {
            width: img.width,
            height: img.height,
            channels,
            pixels,
            mean: (sum / n as f64).as_vec3(),
            mean_luminance: (sum_lum / n as f64) as f32,
            max_value,
            min_value_1,
        })
    }

    fn texel(&self, x: usize, y: usize) -> Vec3 {
        let i = y * self.width + x;
        if self.channels == 1 {
            Vec3::splat(self.pixels[i])
        } else {
            Vec3::new(self.pixels[3 * i], self.pixels[3 * i + 1], self.pixels[3 * i + 2])
        }
    }

    /// Loads `path` once per (file, raw) pair; later requests share the pixels while any texture
    /// still holds them.
    pub fn load_cached(path: &Path, raw: bool) -> Result<Arc<BitmapData>, String> {
        type Cache = Mutex<HashMap<(PathBuf, bool), Weak<BitmapData>>>;
        static CACHE: OnceLock<Cache> = OnceLock::new();
        let key_path = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
        let key = (key_path, raw);
        let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
        // A poisoned lock only means another loader panicked; the map itself is still valid.
        let mut map = cache.lock().unwrap_or_else(|e| e.into_inner());
        crate::resources::note_input_file(path);
        if let Some(data) = map.get(&key).and_then(Weak::upgrade) {
            return Ok(data);
        }
        let img = crate::image::read_image(path, !raw).map_err(|e| format!("{e:#}"))?;
        let data = Arc::new(BitmapData::from_image(&img)?);
        map.retain(|_, w| w.strong_count() > 0);
        map.insert(key, Arc::downgrade(&data));
        Ok(data)
    }
}

fn sanitize(v: f32) -> f32 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

#[derive(Clone, Debug)]
pub struct BitmapTexture {
    pub name: String,
    pub data: Arc<BitmapData>,
    pub filter: FilterType,
    pub wrap: WrapMode,
    /// `None` for the identity.
    pub to_uv: Option<Mat4>,
}

impl BitmapTexture {
    /// A texture over already-decoded pixels (linear values).
    pub fn from_image(
        img: &ImageBuf,
        filter: FilterType,
        wrap: WrapMode,
        to_uv: Option<Mat4>,
    ) -> Result<BitmapTexture, String> {
        Ok(BitmapTexture {
            name: "<image>".into(),
            data: Arc::new(BitmapData::from_image(img)?),
            filter,
            wrap,
            to_uv,
        })
    }

    pub fn from_props(props: &Props, base_dir: &Path) -> Result<BitmapTexture, SceneError> {
        props.expect_only(&["filename", "filter_type", "wrap_mode", "raw", "to_uv"], &[])?;
        let filename = props
            .string_opt("filename")?
            .ok_or_else(|| props.error("a bitmap texture needs a 'filename'"))?;
        let filter = match props.string("filter_type", "bilinear")?.as_str() {
            "bilinear" => FilterType::Bilinear,
            "nearest" => FilterType::Nearest,
            other => {
                return Err(props.error_at(
                    "filter_type",
                    format!("invalid filter_type '{other}' (expected bilinear or nearest)"),
                ))
            }
        };
        let wrap = match props.string("wrap_mode", "repeat")?.as_str() {
            "repeat" => WrapMode::Repeat,
            "mirror" => WrapMode::Mirror,
            "clamp" => WrapMode::Clamp,
            other => {
                return Err(props.error_at(
                    "wrap_mode",
                    format!("invalid wrap_mode '{other}' (expected repeat, mirror or clamp)"),
                ))
            }
        };
        let raw = props.bool("raw", false)?;
        let to_uv = props.transform("to_uv")?;
        let path = base_dir.join(&filename);
        let data = BitmapData::load_cached(&path, raw)
            .map_err(|e| props.error(format!("cannot load bitmap '{}': {e}", path.display())))?;
        Ok(BitmapTexture {
            name: filename,
            data,
            filter,
            wrap,
            to_uv: (to_uv != Mat4::IDENTITY).then_some(to_uv),
        })
    }

    fn wrap_index(&self, i: i64, res: usize) -> usize {
        let res = res as i64;
        let w = match self.wrap {
            WrapMode::Clamp => i.clamp(0, res - 1),
            WrapMode::Repeat => i.rem_euclid(res),
            WrapMode::Mirror => {
                let m = i.rem_euclid(2 * res);
                if m >= res {
                    2 * res - 1 - m
                } else {
                    m
                }
            }
        };
        w as usize
    }

    pub fn eval(&self, uv: Vec2) -> Spectrum {
        let mut uv = match &self.to_uv {
            Some(m) => apply_to_uv(m, uv),
            None => uv,
        };
        if !uv.is_finite() {
            uv = Vec2::ZERO;
        }
        let d = &*self.data;
        let (w, h) = (d.width as f64, d.height as f64);
        match self.filter {
            FilterType::Nearest => {
                let x = (uv.x as f64 * w).floor() as i64;
                let y = (uv.y as f64 * h).floor() as i64;
                d.texel(self.wrap_index(x, d.width), self.wrap_index(y, d.height))
            }
            FilterType::Bilinear => {
                let px = uv.x as f64 * w - 0.5;
                let py = uv.y as f64 * h - 0.5;
                let (fx, fy) = (px.floor(), py.floor());
                let (tx, ty) = ((px - fx) as f32, (py - fy) as f32);
                let (x0, y0) = (fx as i64, fy as i64);
                let xa = self.wrap_index(x0, d.width);
                let xb = self.wrap_index(x0.saturating_add(1), d.width);
                let ya = self.wrap_index(y0, d.height);
                let yb = self.wrap_index(y0.saturating_add(1), d.height);
                let top = d.texel(xa, ya) * (1.0 - tx) + d.texel(xb, ya) * tx;
                let bottom = d.texel(xa, yb) * (1.0 - tx) + d.texel(xb, yb) * tx;
                top * (1.0 - ty) + bottom * ty
            }
        }
    }

    pub fn eval_1(&self, uv: Vec2) -> f32 {
        let v = self.eval(uv);
        if self.data.channels == 1 {
            v.x
        } else {
            luminance(v)
        }
    }

    pub fn mean(&self) -> Spectrum {
        self.data.mean
    }

    pub fn mean_luminance(&self) -> f32 {
        self.data.mean_luminance
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 2×2 RGB image: row 0 = red, green; row 1 = blue, white.
    fn quad() -> ImageBuf {
        let mut img = ImageBuf::new(2, 2, 3);
        img.data = vec![
            1.0, 0.0, 0.0, 0.0, 1.0, 0.0, //
            0.0, 0.0, 1.0, 1.0, 1.0, 1.0,
        ];
        img
    }

    #[test]
    fn orientation_and_texel_centres() {
        let t = BitmapTexture::from_image(&quad(), FilterType::Bilinear, WrapMode::Clamp, None).unwrap();
        // uv (0,0) is the first stored row, first column.
        assert_eq!(t.eval(Vec2::new(0.25, 0.25)), Vec3::new(1.0, 0.0, 0.0));
        assert_eq!(t.eval(Vec2::new(0.75, 0.25)), Vec3::new(0.0, 1.0, 0.0));
        assert_eq!(t.eval(Vec2::new(0.25, 0.75)), Vec3::new(0.0, 0.0, 1.0));
        // Half-way between the two top texel centres.
        let mid = t.eval(Vec2::new(0.5, 0.25));
        assert!((mid - Vec3::new(0.5, 0.5, 0.0)).abs().max_element() < 1e-6);
        assert!((t.mean() - Vec3::new(0.5, 0.5, 0.5)).abs().max_element() < 1e-6);
    }

    #[test]
    fn wrap_modes() {
        let mut img = ImageBuf::new(4, 1, 1);
        img.data = vec![0.0, 1.0, 2.0, 3.0];
        let at = |wrap, u: f32| {
            BitmapTexture::from_image(&img, FilterType::Nearest, wrap, None)
                .unwrap()
                .eval(Vec2::new(u, 0.5))
                .x
        };
        // Texel -1 (u in [-0.25, 0)).
        assert_eq!(at(WrapMode::Repeat, -0.1), 3.0);
        assert_eq!(at(WrapMode::Mirror, -0.1), 0.0);
        assert_eq!(at(WrapMode::Clamp, -0.1), 0.0);
        // Texel 5 (u in [1.25, 1.5)).
        assert_eq!(at(WrapMode::Repeat, 1.3), 1.0);
        assert_eq!(at(WrapMode::Mirror, 1.3), 2.0);
        assert_eq!(at(WrapMode::Clamp, 1.3), 3.0);
        // Bilinear repeat blends the last and first texels across the seam.
        let t = BitmapTexture::from_image(&img, FilterType::Bilinear, WrapMode::Repeat, None).unwrap();
        assert!((t.eval(Vec2::new(0.0, 0.5)).x - 1.5).abs() < 1e-6);
        assert_eq!(t.eval(Vec2::new(f32::NAN, 0.5)).x, t.eval(Vec2::ZERO).x);
    }

    #[test]
    fn to_uv_scales_and_translates() {
        let m = Mat4::from_translation(Vec3::new(0.5, 0.0, 0.0)) * Mat4::from_scale(Vec3::new(0.5, 1.0, 1.0));
        let t = BitmapTexture::from_image(&quad(), FilterType::Nearest, WrapMode::Repeat, Some(m)).unwrap();
        // u' = 0.5 u + 0.5: u = 0.1 → 0.55 → right column.
        assert_eq!(t.eval(Vec2::new(0.1, 0.1)), Vec3::new(0.0, 1.0, 0.0));
    }
}
