//! Compiles the OpenImageIO shim and links OpenImageIO (placeholder).

pub fn configure() {}
