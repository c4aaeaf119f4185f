//! Locates Embree 3 and checks the vendored bindings against its headers (placeholder).

pub fn configure() {}
