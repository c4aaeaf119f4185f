//! Isotropic point light (Mitsuba's `point`): `intensity` in W/sr, placed by `position` or `to_world`.

use super::{check_emission, LightSample};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use glam::Vec3;

#[derive(Debug)]
pub struct PointLight {
    pub position: Vec3,
    pub intensity: Spectrum,
}

impl PointLight {
    pub fn from_props(props: &Props) -> Result<PointLight, SceneError> {
        props.expect_only(&["intensity", "position", "to_world"], &[])?;
        let intensity = props.rgb("intensity", Vec3::ONE)?;
        check_emission(props, "intensity", intensity)?;
        let position = match props.point_opt("position")? {
            Some(p) => p,
            None => props.transform("to_world")?.transform_point3(Vec3::ZERO),
        };
        if !position.is_finite() {
            return Err(props.error("the point light's position is not finite"));
        }
        Ok(PointLight { position, intensity })
    }

    pub fn sample_li(&self, p: Vec3) -> Option<LightSample> {
        let d = self.position - p;
        let dist2 = d.length_squared();
        if !(dist2 > 0.0) {
            return None;
        }
        let dist = dist2.sqrt();
        Some(LightSample {
            p: self.position,
            wi: d / dist,
            dist,
            radiance: self.intensity / dist2,
            pdf: 1.0,
            is_delta: true,
        })
    }
}
