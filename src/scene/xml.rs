//! Mitsuba XML parser (placeholder until the parser lands).

use super::{Props, SceneError};
use std::path::Path;

/// Parses a scene file into a root `Props` (tag `scene`) whose entries are the top-level plugins in
/// document order; `defines` are `-D name=value` overrides of `<default>` parameters.
pub fn parse_file(path: &Path, _defines: &[(String, String)]) -> Result<Props, SceneError> {
    Err(SceneError::file(path, "the XML parser is not built yet"))
}
