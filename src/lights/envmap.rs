//! Environment map (Mitsuba 3's `envmap`): an equirectangular image around the scene, +y up, with
//! u = atan2(x, −z)/2π and v = acos(y)/π in the light's local frame (checked against Mitsuba 3).
//! Directions are importance sampled from a piecewise-constant density ∝ luminance · sin θ per pixel.

use super::{check_emission, LightSample};
use crate::geometry::Transform;
use crate::image::ImageBuf;
use crate::props::{Props, SceneError};
use crate::sampling::Distribution1D;
use crate::spectrum::{luminance, Spectrum};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

#[derive(Debug)]
pub struct EnvMap {
    width: usize,
    height: usize,
    pixels: Vec<Spectrum>,
    to_world: Transform,
    /// Marginal over rows and one conditional per row.
    rows: Distribution1D,
    cols: Vec<Option<Distribution1D>>,
    mean_luminance: f32,
}

impl EnvMap {
    pub fn from_props(props: &Props, base_dir: &std::path::Path) -> Result<EnvMap, SceneError> {
        props.expect_only(&["filename", "scale", "to_world"], &[])?;
        let filename =
            props.string_opt("filename")?.ok_or_else(|| props.error("the envmap needs a 'filename'"))?;
        let path = base_dir.join(&filename);
        let img = crate::image::read_image(&path, true)
            .map_err(|e| props.error_at("filename", format!("cannot read environment map: {e:#}")))?;
        crate::resources::note_input_file(&path);
        let scale = props.float("scale", 1.0)?;
        let to_world = Transform::new(props.transform("to_world")?)
            .ok_or_else(|| props.error_at("to_world", "the envmap's to_world matrix is singular"))?;
        let env = EnvMap::from_image(&img, scale, to_world).map_err(|m| props.error(m))?;
        check_emission(props, "scale", Vec3::splat(scale))?;
        Ok(env)
    }

    pub fn from_image(img: &ImageBuf, scale: f32, to_world: Transform) -> Result<EnvMap, String> {
        let (w, h) = (img.width, img.height);
        if w == 0 || h == 0 {
            return Err("the environment map is empty".into());
        }
        let mut pixels = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let px = img.pixel(x, y);
                let c = match img.channels {
                    1 | 2 => Vec3::splat(px[0]),
                    _ => Vec3::new(px[0], px[1], px[2]),
                } * scale;
                if !c.is_finite() || c.min_element() < 0.0 {
                    return Err(format!("pixel ({x}, {y}) of the environment map is negative or not finite"));
                }
                pixels.push(c);
            }
        }
        let mut row_weights = Vec::with_capacity(h);
        let mut cols = Vec::with_capacity(h);
        let mut lum_sum = 0.0f64;
        for y in 0..h {
            let sin_theta = (PI * (y as f32 + 0.5) / h as f32).sin();
            let weights: Vec<f64> =
                (0..w).map(|x| (luminance(pixels[y * w + x]) * sin_theta) as f64).collect();
            lum_sum += (0..w).map(|x| luminance(pixels[y * w + x]) as f64 * sin_theta as f64).sum::<f64>();
            row_weights.push(weights.iter().sum::<f64>());
            cols.push(Distribution1D::new(&weights));
        }
        let rows = Distribution1D::new(&row_weights).ok_or("the environment map is black everywhere")?;
        // Mean over the sphere: Σ L sinθ ΔθΔφ / 4π with Δθ = π/h, Δφ = 2π/w.
        let mean_luminance =
            (lum_sum * (PI as f64 / h as f64) * (2.0 * PI as f64 / w as f64) / (4.0 * PI as f64)) as f32;
        Ok(EnvMap { width: w, height: h, pixels, to_world, rows, cols, mean_luminance })
    }

    pub fn mean_luminance(&self) -> f32 {
        self.mean_luminance
    }

    fn local_to_uv(d: Vec3) -> Vec2 {
        let mut u = d.x.atan2(-d.z) / (2.0 * PI);
        if u < 0.0 {
            u += 1.0;
        }
        Vec2::new(u, d.y.clamp(-1.0, 1.0).acos() / PI)
    }

    fn uv_to_local(uv: Vec2) -> Vec3 {
        let phi = uv.x * 2.0 * PI;
        let theta = uv.y * PI;
        let (st, ct) = theta.sin_cos();
        Vec3::new(st * phi.sin(), ct, -st * phi.cos())
    }

    /// Bilinear lookup with horizontal wrap and vertical clamp, pixel centres at half-integers.
    fn lookup(&self, uv: Vec2) -> Spectrum {
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let w = self.width as i64;
        let h = self.height as i64;
        let px = |xi: i64, yi: i64| {
            let xi = xi.rem_euclid(w) as usize;
            let yi = yi.clamp(0, h - 1) as usize;
            self.pixels[yi * self.width + xi]
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        (px(x0, y0) * (1.0 - fx) + px(x0 + 1, y0) * fx) * (1.0 - fy)
            + (px(x0, y0 + 1) * (1.0 - fx) + px(x0 + 1, y0 + 1) * fx) * fy
    }

    /// Radiance seen when looking along world direction `dir`.
    pub fn eval(&self, dir: Vec3) -> Spectrum {
        let local = self.to_world.inverse.transform_vector3(dir).normalize_or_zero();
        self.lookup(Self::local_to_uv(local))
    }

    /// Solid-angle density of `sample_li` returning `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let local = self.to_world.inverse.transform_vector3(dir).normalize_or_zero();
        let uv = Self::local_to_uv(local);
        let x = ((uv.x * self.width as f32) as usize).min(self.width - 1);
        let y = ((uv.y * self.height as f32) as usize).min(self.height - 1);
        let p_row = self.rows.pmf(y);
        let p_col = self.cols[y].as_ref().map_or(0.0, |c| c.pmf(x));
        let sin_theta = (PI * uv.y).sin();
        if sin_theta <= 1e-6 {
            return 0.0;
        }
        // Density in (u, v) is p · w · h; dω = 2π² sinθ du dv.
        p_row * p_col * (self.width * self.height) as f32 / (2.0 * PI * PI * sin_theta)
    }

    pub fn sample_li(&self, p: Vec3, u: Vec2, scene_radius: f32) -> Option<LightSample> {
        let (y, uy) = self.rows.sample(u.y);
        let (x, ux) = self.cols[y].as_ref()?.sample(u.x);
        let uv = Vec2::new((x as f32 + ux) / self.width as f32, (y as f32 + uy) / self.height as f32);
        let local = Self::uv_to_local(uv);
        let wi = self.to_world.vector(local).normalize_or_zero();
        let pdf = self.pdf(wi);
        if !(pdf > 0.0) || !pdf.is_finite() {
            return None;
        }
        Some(LightSample {
            p: p + wi * 2.0 * scene_radius,
            wi,
            dist: f32::INFINITY,
            radiance: self.eval(wi),
            pdf,
            is_delta: false,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uv_mapping_round_trips_and_matches_mitsuba_axes() {
        // Mitsuba 3: -z maps to u = 0, +x to u = 0.25, +z to 0.5, -x to 0.75; +y is the top row.
        let uv = EnvMap::local_to_uv(Vec3::new(1.0, 0.0, 0.0));
        assert!((uv - Vec2::new(0.25, 0.5)).length() < 1e-6, "{uv}");
        assert!(EnvMap::local_to_uv(Vec3::Y).y < 1e-6);
        for &d in &[Vec3::new(0.3, 0.5, -0.8), Vec3::new(-0.6, -0.2, 0.77), Vec3::new(0.1, 0.9, 0.4)] {
            let d = d.normalize();
            let back = EnvMap::uv_to_local(EnvMap::local_to_uv(d));
            assert!((back - d).length() < 1e-5, "{d} -> {back}");
        }
    }

    #[test]
    fn sampling_density_matches_pdf_and_integrates_to_one() {
        let mut img = ImageBuf::new(16, 8, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = 0.1 + ((i * 7919) % 13) as f32;
        }
        let env = EnvMap::from_image(&img, 1.0, Transform::default()).unwrap();
        // ∫ pdf dω over the sphere by a fine (θ, φ) quadrature.
        let n = 400;
        let mut integral = 0.0f64;
        for i in 0..n {
            for j in 0..2 * n {
                let theta = PI * (i as f32 + 0.5) / n as f32;
                let phi = 2.0 * PI * (j as f32 + 0.5) / (2 * n) as f32;
                let d = Vec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos());
                integral +=
                    (env.pdf(d) * theta.sin()) as f64 * (PI as f64 / n as f64) * (PI as f64 / n as f64);
            }
        }
        assert!((integral - 1.0).abs() < 5e-3, "∫pdf = {integral}");
        // Each sample's reported pdf equals pdf(dir), and the radiance is finite.
        let mut s = crate::sampling::Sampler::new(1, 2, 3);
        for _ in 0..1000 {
            let ls = env.sample_li(Vec3::ZERO, s.next_2d(), 1.0).unwrap();
            assert!((ls.pdf - env.pdf(ls.wi)).abs() <= 1e-3 * ls.pdf);
            assert!(ls.radiance.is_finite());
        }
    }
}
