//! Small scenes the stability cases build from XML text, and the scene files they load from the
//! repository, so every case is self-contained.

use std::path::{Path, PathBuf};

use crate::accel::AccelKind;
use crate::scene::{LoadOptions, Scene};

/// Builds a scene from XML text; `name` labels it in error messages.
pub fn from_xml(name: &str, xml: &str) -> Scene {
    let path = PathBuf::from(format!("<stability:{name}>"));
    let options = LoadOptions { defines: Vec::new(), accel: AccelKind::Embree };
    Scene::load_str(xml, &path, &options).unwrap_or_else(|e| panic!("stability scene {name}: {e:#}"))
}

/// Where the bundled scenes are: the source tree this binary was built from, else the Debian package's
/// copy.
fn bundled_path(rel: &str) -> PathBuf {
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    if source.exists() {
        return source;
    }
    Path::new("/usr/share/hslt").join(rel)
}

/// Loads a bundled scene (`scenes/...`) with overrides.
pub fn bundled(rel: &str, defines: &[(&str, &str)]) -> Scene {
    let path = bundled_path(rel);
    let defines = defines.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    Scene::load(&path, &LoadOptions { defines, accel: AccelKind::Embree })
        .unwrap_or_else(|e| panic!("{rel}: {e:#}"))
}
