//! Pinhole perspective camera with Mitsuba 3's conventions: camera space looks down +z with +y up,
//! and the image's left edge maps to camera +x (so `to_world` matrices from Mitsuba scenes work as is).

use crate::geometry::{Ray, Transform, Vec2, Vec3};
use crate::props::{Props, SceneError};

#[derive(Clone, Debug)]
pub struct PerspectiveCamera {
    pub to_world: Transform,
    /// tan of the half field of view along x and y.
    pub tan_half: Vec2,
    pub near_clip: f32,
    pub far_clip: f32,
    pub width: usize,
    pub height: usize,
}

impl PerspectiveCamera {
    /// Reads `<sensor type="perspective">`; `width`/`height` come from the film (they fix the aspect).
    pub fn from_props(props: &Props, width: usize, height: usize) -> Result<PerspectiveCamera, SceneError> {
        if props.plugin_type != "perspective" {
            return Err(props
                .error(format!("unsupported sensor type '{}' (supported: perspective)", props.plugin_type)));
        }
        props.expect_only(
            &[
                "fov",
                "fov_axis",
                "near_clip",
                "far_clip",
                "to_world",
                "focal_length",
                "principal_point_offset_x",
                "principal_point_offset_y",
            ],
            &["film", "sampler"],
        )?;
        let aspect = width as f32 / height as f32;
        if props.has("focal_length") {
            return Err(props.error_at(
                "focal_length",
                "give the field of view as 'fov' (degrees); 'focal_length' is not supported",
            ));
        }
        let fov = props
            .float_opt("fov")?
            .ok_or_else(|| props.error("the perspective sensor needs a 'fov' (in degrees)"))?;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(
                props.error_at("fov", format!("fov {fov} must lie strictly between 0 and 180 degrees"))
            );
        }
        if props.float("principal_point_offset_x", 0.0)? != 0.0
            || props.float("principal_point_offset_y", 0.0)? != 0.0
        {
            return Err(props.error("principal point offsets are not supported"));
        }
        let t = (fov.to_radians() * 0.5).tan();
        let axis = props.string("fov_axis", "x")?;
        let tan_half = match axis.as_str() {
            "x" => Vec2::new(t, t / aspect),
            "y" => Vec2::new(t * aspect, t),
            "diagonal" => {
                let diag = (1.0 + 1.0 / (aspect * aspect)).sqrt();
                let tx = t / diag;
                Vec2::new(tx, tx / aspect)
            }
            "smaller" => {
                if aspect > 1.0 {
                    Vec2::new(t * aspect, t)
                } else {
                    Vec2::new(t, t / aspect)
                }
            }
            "larger" => {
                if aspect > 1.0 {
                    Vec2::new(t, t / aspect)
                } else {
                    Vec2::new(t * aspect, t)
                }
            }
            other => {
                return Err(props.error_at(
                    "fov_axis",
                    format!("fov_axis '{other}' is not one of x, y, diagonal, smaller, larger"),
                ))
            }
        };
        let near_clip = props.float("near_clip", 0.01)?;
        let far_clip = props.float("far_clip", 10000.0)?;
        if !(near_clip >= 0.0 && far_clip > near_clip) {
            return Err(props.error("near_clip must be >= 0 and below far_clip"));
        }
        let m = props.transform("to_world")?;
        let to_world = Transform::new(m)
            .ok_or_else(|| props.error_at("to_world", "the sensor's to_world matrix is singular"))?;
        Ok(PerspectiveCamera { to_world, tan_half, near_clip, far_clip, width, height })
    }

    /// Position of the pinhole in world space.
    pub fn position(&self) -> Vec3 {
        self.to_world.point(Vec3::ZERO)
    }

    /// The primary ray through continuous film position `film` (pixels, origin top-left).
    pub fn generate_ray(&self, film: Vec2) -> Ray {
        let sx = film.x / self.width as f32;
        let sy = film.y / self.height as f32;
        let local = Vec3::new((1.0 - 2.0 * sx) * self.tan_half.x, (1.0 - 2.0 * sy) * self.tan_half.y, 1.0);
        // Clip distances are measured in camera space, as Mitsuba does, so a scaled to_world scales them.
        let world = self.to_world.vector(local);
        let len = world.length();
        let dir = world / len;
        Ray { origin: self.position(), dir, tmin: self.near_clip * len, tmax: self.far_clip * len }
    }

    /// Unit viewing axis in world space (the camera's "normal" in the geometry term).
    pub fn forward(&self) -> Vec3 {
        self.to_world.vector(Vec3::Z).normalize()
    }

    /// Cosine between `dir` and the viewing axis, measured in camera space.
    fn cos_theta(&self, dir: Vec3) -> f32 {
        let local = self.to_world.inverse.transform_vector3(dir);
        local.z / local.length()
    }

    /// Solid-angle density of the primary-ray direction `dir` when film positions are uniform over the
    /// image: 1 / (A cos³θ), A the image-plane area at unit distance (Veach 1997, §10.3; pbrt's Pdf_We).
    /// Bidirectional MIS compares every strategy against this density.
    pub fn pdf_dir(&self, dir: Vec3) -> f32 {
        let cos = self.cos_theta(dir);
        if !(cos > 0.0) || self.film_position(dir).is_none() {
            return 0.0;
        }
        1.0 / (4.0 * self.tan_half.x * self.tan_half.y * cos * cos * cos)
    }

    /// Sensor importance W(dir) = pdf_dir / cos θ, normalised so that a light path connected to the
    /// pinhole estimates the whole image at once: splats of f/p then average to each pixel's value
    /// when divided by the number of light paths per pixel.
    pub fn importance(&self, dir: Vec3) -> f32 {
        let cos = self.cos_theta(dir);
        if !(cos > 0.0) {
            return 0.0;
        }
        self.pdf_dir(dir) / cos
    }

    /// Film position of a world-space direction leaving the pinhole, if it lands inside the image.
    pub fn film_position(&self, dir: Vec3) -> Option<Vec2> {
        let local = self.to_world.inverse.transform_vector3(dir);
        if local.z <= 0.0 {
            return None;
        }
        let x = local.x / local.z / self.tan_half.x;
        let y = local.y / local.z / self.tan_half.y;
        let film = Vec2::new((1.0 - x) * 0.5 * self.width as f32, (1.0 - y) * 0.5 * self.height as f32);
        (film.x >= 0.0 && film.y >= 0.0 && film.x < self.width as f32 && film.y < self.height as f32)
            .then_some(film)
    }
}
