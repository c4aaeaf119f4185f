//! Shape plugins: meshes from OBJ/PLY files and tessellated analytic shapes (placeholder).

use crate::geometry::TriangleMesh;
use crate::scene::{Props, SceneError};
use std::path::Path;

/// A shape turned into world-space triangles, with any warnings (e.g. skipped degenerate triangles).
#[derive(Debug, Default)]
pub struct LoadedShape {
    pub mesh: TriangleMesh,
    pub warnings: Vec<String>,
}

/// Loads the geometry of a `<shape>` element; relative file names resolve against `base_dir`.
pub fn load_shape(props: &Props, _base_dir: &Path) -> Result<LoadedShape, SceneError> {
    Err(props.error(format!("unsupported shape type '{}'", props.plugin_type)))
}
