//! Textures for BSDF and emitter parameters (placeholder: constants only until the texture library lands).

use crate::scene::{Props, SceneError};
use crate::spectrum::Spectrum;
use glam::Vec2;

#[derive(Clone, Debug)]
pub enum Texture {
    Constant(Spectrum),
}

impl Texture {
    pub fn eval(&self, _uv: Vec2) -> Spectrum {
        match self {
            Texture::Constant(c) => *c,
        }
    }

    /// Mean value over the texture's domain (used for light power estimates and albedo guesses).
    pub fn mean(&self) -> Spectrum {
        match self {
            Texture::Constant(c) => *c,
        }
    }

    /// Reads parameter `name` as a colour or a nested texture; `default` when absent.
    pub fn from_param(props: &Props, name: &str, default: Spectrum) -> Result<Texture, SceneError> {
        Ok(Texture::Constant(props.rgb(name, default)?))
    }
}
