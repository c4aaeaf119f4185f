//! Build script: finds and checks the system Embree and (with the `oiio` feature) compiles the
//! OpenImageIO shim. The logic lives in `build-support/`, one file per native dependency.

#[path = "build-support/embree.rs"]
mod embree;
#[path = "build-support/oiio.rs"]
mod oiio;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=build-support");
    embree::configure();
    if std::env::var_os("CARGO_FEATURE_OIIO").is_some() {
        oiio::configure();
    }
}
