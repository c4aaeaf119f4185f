//! Spot light (Mitsuba 3's `spot`): a point light restricted to a cone around local +z, full
//! intensity inside `beam_width` and a linear fall-off in angle out to `cutoff_angle`.

use super::{check_emission, LightSample};
use crate::geometry::Transform;
use crate::props::{Props, SceneError};
use crate::spectrum::{luminance, Spectrum};
use glam::Vec3;
use std::f32::consts::PI;

#[derive(Debug)]
pub struct SpotLight {
    pub to_world: Transform,
    pub intensity: Spectrum,
    cutoff: f32,
    beam: f32,
}

impl SpotLight {
    pub fn from_props(props: &Props) -> Result<SpotLight, SceneError> {
        props.expect_only(&["intensity", "cutoff_angle", "beam_width", "to_world"], &[])?;
        let intensity = props.rgb("intensity", Vec3::ONE)?;
        check_emission(props, "intensity", intensity)?;
        let cutoff_deg = props.float("cutoff_angle", 20.0)?;
        let beam_deg = props.float("beam_width", cutoff_deg * 0.75)?;
        if !(cutoff_deg > 0.0 && cutoff_deg <= 180.0) {
            return Err(props.error_at("cutoff_angle", "cutoff_angle must lie in (0, 180] degrees"));
        }
        if !(beam_deg > 0.0 && beam_deg <= cutoff_deg) {
            return Err(props.error_at("beam_width", "beam_width must lie in (0, cutoff_angle] degrees"));
        }
        let to_world = Transform::new(props.transform("to_world")?)
            .ok_or_else(|| props.error_at("to_world", "the spot light's to_world matrix is singular"))?;
        Ok(SpotLight { to_world, intensity, cutoff: cutoff_deg.to_radians(), beam: beam_deg.to_radians() })
    }

    pub fn position(&self) -> Vec3 {
        self.to_world.point(Vec3::ZERO)
    }

    /// Angular fall-off for a world direction leaving the light.
    pub fn falloff(&self, dir: Vec3) -> f32 {
        let local = self.to_world.inverse.transform_vector3(dir).normalize_or_zero();
        let theta = local.z.clamp(-1.0, 1.0).acos();
        if theta >= self.cutoff {
            0.0
        } else if theta <= self.beam {
            1.0
        } else {
            (self.cutoff - theta) / (self.cutoff - self.beam)
        }
    }

    pub fn sample_li(&self, p: Vec3) -> Option<LightSample> {
        let pos = self.position();
        let d = pos - p;
        let dist2 = d.length_squared();
        if !(dist2 > 0.0) {
            return None;
        }
        let dist = dist2.sqrt();
        let wi = d / dist;
        let f = self.falloff(-wi);
        if f <= 0.0 {
            return None;
        }
        Some(LightSample {
            p: pos,
            wi,
            dist,
            radiance: self.intensity * (f / dist2),
            pdf: 1.0,
            is_delta: true,
        })
    }

    /// Samples an emission direction uniformly inside the cut-off cone: (direction, solid-angle pdf).
    pub fn sample_direction(&self, u: glam::Vec2) -> (Vec3, f32) {
        let cos_max = self.cutoff.cos();
        let local = crate::sampling::square_to_uniform_cone(u, cos_max);
        let dir = self.to_world.vector(local).normalize_or_zero();
        (dir, crate::sampling::uniform_cone_pdf(cos_max))
    }

    /// Density of `sample_direction` producing `dir`.
    pub fn pdf_direction(&self, dir: Vec3) -> f32 {
        let local = self.to_world.inverse.transform_vector3(dir).normalize_or_zero();
        let cos_max = self.cutoff.cos();
        if local.z >= cos_max {
            crate::sampling::uniform_cone_pdf(cos_max)
        } else {
            0.0
        }
    }

    pub fn power(&self) -> f32 {
        let cone = 2.0 * PI * (1.0 - (0.5 * (self.cutoff + self.beam)).cos());
        cone * luminance(self.intensity)
    }
}
