//! Scene errors that point at the file, line and element at fault, so a user can fix the input
//! without reading our source.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A position in a scene file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SrcLoc {
    pub file: Arc<PathBuf>,
    pub line: u32,
    pub col: u32,
}

impl SrcLoc {
    pub fn new(file: &Path, line: u32, col: u32) -> SrcLoc {
        SrcLoc { file: Arc::new(file.to_path_buf()), line, col }
    }

    /// A location for things that come from no file (CLI overrides, built-in defaults).
    pub fn builtin() -> SrcLoc {
        SrcLoc { file: Arc::new(PathBuf::from("<builtin>")), line: 0, col: 0 }
    }
}

impl fmt::Display for SrcLoc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 {
            write!(f, "{}", self.file.display())
        } else {
            write!(f, "{}:{}:{}", self.file.display(), self.line, self.col)
        }
    }
}

/// An error in a scene description, with where it happened and what was expected.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneError {
    pub loc: SrcLoc,
    /// The element at fault, e.g. `<bsdf type="foo">` or `shape 'Floor'`.
    pub element: Option<String>,
    pub message: String,
}

impl SceneError {
    pub fn new(loc: SrcLoc, element: Option<String>, message: impl Into<String>) -> SceneError {
        SceneError { loc, element, message: message.into() }
    }

    /// An error about a whole file (unreadable, not XML, truncated mesh...).
    pub fn file(path: &Path, message: impl Into<String>) -> SceneError {
        SceneError { loc: SrcLoc::new(path, 0, 0), element: None, message: message.into() }
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.element {
            Some(e) => write!(f, "{}: {}: {}", self.loc, e, self.message),
            None => write!(f, "{}: {}", self.loc, self.message),
        }
    }
}

impl std::error::Error for SceneError {}
