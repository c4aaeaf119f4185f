//! `checkerboard`: a procedural two-colour checkerboard, as Mitsuba 3's `checkerboard` plugin.
//!
//! | Parameter | Type              | Default  | Meaning                                          |
//! |-----------|-------------------|----------|--------------------------------------------------|
//! | `color0`  | spectrum/texture  | 0.4      | colour of the cells where u and v agree          |
//! | `color1`  | spectrum/texture  | 0.2      | colour of the other cells                        |
//! | `to_uv`   | transform         | identity | applied to uv first (2×2 block + translation)    |
//!
//! Mitsuba's rule: with f = uv − ⌊uv⌋, a point gets `color0` when (f.u > ½) == (f.v > ½), else `color1`;
//! so the unit square holds a 2×2 board with `color0` at its lower-left and upper-right cells.

use super::{apply_to_uv, Texture};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use glam::{Mat4, Vec2, Vec3};
use std::path::Path;

#[derive(Clone, Debug)]
pub struct Checkerboard {
    pub color0: Texture,
    pub color1: Texture,
    pub to_uv: Mat4,
}

impl Checkerboard {
    pub fn from_props(props: &Props, base_dir: &Path) -> Result<Checkerboard, SceneError> {
        props.expect_only(&["color0", "color1", "to_uv"], &[])?;
        Ok(Checkerboard {
            color0: Texture::from_param_in(props, "color0", Vec3::splat(0.4), base_dir)?,
            color1: Texture::from_param_in(props, "color1", Vec3::splat(0.2), base_dir)?,
            to_uv: props.transform("to_uv")?,
        })
    }

    fn picks_color0(&self, uv: Vec2) -> bool {
        let p = apply_to_uv(&self.to_uv, uv);
        let f = p - p.floor();
        (f.x > 0.5) == (f.y > 0.5)
    }

    pub fn eval(&self, uv: Vec2) -> Spectrum {
        if self.picks_color0(uv) {
            self.color0.eval(uv)
        } else {
            self.color1.eval(uv)
        }
    }

    pub fn eval_1(&self, uv: Vec2) -> f32 {
        if self.picks_color0(uv) {
            self.color0.eval_1(uv)
        } else {
            self.color1.eval_1(uv)
        }
    }

    pub fn mean(&self) -> Spectrum {
        0.5 * (self.color0.mean() + self.color1.mean())
    }
}
