//! Safe wrapper around Embree 3 (placeholder until the FFI lands).

use super::{Hit, RayQuery};
use crate::geometry::{Ray, TriangleMesh};

pub struct EmbreeScene {}

impl EmbreeScene {
    pub fn build(_meshes: &[TriangleMesh]) -> anyhow::Result<EmbreeScene> {
        anyhow::bail!("the Embree backend is not built yet")
    }
}

impl RayQuery for EmbreeScene {
    fn name(&self) -> &'static str {
        "embree"
    }
    fn intersect(&self, _ray: &Ray) -> Option<Hit> {
        None
    }
    fn occluded(&self, _ray: &Ray) -> bool {
        false
    }
}
