//! Scene loading: Mitsuba XML (both 3.x and 0.6 spellings) into plugin properties, then into the
//! render-ready scene: world-space meshes, BSDFs, lights, sensor and film, built only as far as the
//! scene needs them.

pub mod error;
pub mod props;

pub use error::{SceneError, SrcLoc};
pub use props::{Prop, PropValue, Props};
pub mod shapes;
pub mod xml;
