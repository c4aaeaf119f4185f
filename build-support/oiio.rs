//! Compiles the OpenImageIO C++ shim (`src/image/oiio_shim.cpp`) and links OpenImageIO.
//! The library is found through pkg-config (`OpenImageIO`), or under `$OIIO_DIR/{include,lib}`
//! when that variable is set (for installs outside the system prefix).

use std::env;
use std::path::PathBuf;
use std::process::Command;

const SHIM: &str = "src/image/oiio_shim.cpp";
const LIBS: [&str; 2] = ["OpenImageIO", "OpenImageIO_Util"];

/// Where the OpenImageIO headers and libraries are, and any extra compiler flags.
struct OiioLocation {
    include_dirs: Vec<PathBuf>,
    lib_dirs: Vec<PathBuf>,
    libs: Vec<String>,
    defines: Vec<(String, Option<String>)>,
    /// Set for a non-system prefix, whose libraries the loader would not otherwise find.
    rpath: Option<PathBuf>,
}

pub fn configure() {
    println!("cargo:rerun-if-env-changed=OIIO_DIR");
    println!("cargo:rerun-if-changed={SHIM}");

    let location = match env::var_os("OIIO_DIR") {
        Some(dir) => from_prefix(PathBuf::from(dir)),
        None => from_pkg_config().unwrap_or_else(|why| {
            panic!(
                "OpenImageIO not found: {why}.\n\
                 Install it (Debian: libopenimageio-dev), set OIIO_DIR to a prefix holding \
                 include/OpenImageIO and lib/libOpenImageIO.so, or build without it using \
                 `--no-default-features` (EXR and PNG only)."
            )
        }),
    };

    // The shim becomes a shared library of its own, linked against OpenImageIO, which the binary
    // opens on first use (src/image/oiio.rs): linked into the binary, OpenImageIO's 250-odd
    // dependencies were loaded into every process.
    let mut build = cc::Build::new();
    build.cpp(true).std("c++17").file(SHIM).warnings(true).pic(true);
    for dir in &location.include_dirs {
        build.include(dir);
    }
    for (name, value) in &location.defines {
        build.define(name, value.as_deref());
    }
    let objects = build.compile_intermediates();
    let out_dir = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let shim = out_dir.join("libhslt_oiio.so");
    let mut link = build.get_compiler().to_command();
    link.arg("-shared").arg("-o").arg(&shim).args(&objects).arg("-Wl,--no-undefined");
    for dir in &location.lib_dirs {
        link.arg(format!("-L{}", dir.display()));
    }
    for lib in &location.libs {
        link.arg(format!("-l{lib}"));
    }
    if let Some(rpath) = &location.rpath {
        link.arg(format!("-Wl,-rpath,{}", rpath.display()));
    }
    let status =
        link.status().unwrap_or_else(|e| panic!("could not run the C++ compiler to link {SHIM}: {e}"));
    if !status.success() {
        panic!("linking {} failed ({status})", shim.display());
    }
    println!("cargo:rustc-env=HSLT_OIIO_SHIM_BUILT={}", shim.display());
}

fn from_prefix(prefix: PathBuf) -> OiioLocation {
    let header = prefix.join("include/OpenImageIO/imageio.h");
    if !header.is_file() {
        panic!("OIIO_DIR={} does not contain include/OpenImageIO/imageio.h", prefix.display());
    }
    let lib_dirs: Vec<PathBuf> =
        ["lib", "lib64"].iter().map(|sub| prefix.join(sub)).filter(|dir| dir.is_dir()).collect();
    if lib_dirs.is_empty() {
        panic!("OIIO_DIR={} has neither lib/ nor lib64/", prefix.display());
    }
    OiioLocation {
        include_dirs: vec![prefix.join("include")],
        rpath: lib_dirs.first().cloned(),
        lib_dirs,
        libs: LIBS.iter().map(|s| s.to_string()).collect(),
        defines: Vec::new(),
    }
}

fn from_pkg_config() -> Result<OiioLocation, String> {
    let output = Command::new("pkg-config")
        .args(["--cflags", "--libs", "OpenImageIO"])
        .output()
        .map_err(|e| format!("could not run pkg-config ({e})"))?;
    if !output.status.success() {
        return Err(format!(
            "`pkg-config --cflags --libs OpenImageIO` failed: {}",
            String::from_utf8_lossy(&output.stderr).trim()
        ));
    }
    let mut location = OiioLocation {
        include_dirs: Vec::new(),
        lib_dirs: Vec::new(),
        libs: Vec::new(),
        defines: Vec::new(),
        rpath: None,
    };
    for flag in String::from_utf8_lossy(&output.stdout).split_whitespace() {
        if let Some(dir) = flag.strip_prefix("-I") {
            location.include_dirs.push(PathBuf::from(dir));
        } else if let Some(dir) = flag.strip_prefix("-L") {
            location.lib_dirs.push(PathBuf::from(dir));
        } else if let Some(lib) = flag.strip_prefix("-l") {
            location.libs.push(lib.to_string());
        } else if let Some(define) = flag.strip_prefix("-D") {
            let (name, value) = match define.split_once('=') {
                Some((n, v)) => (n.to_string(), Some(v.to_string())),
                None => (define.to_string(), None),
            };
            location.defines.push((name, value));
        }
    }
    // Older .pc files list only OpenImageIO; the shim also uses the Util library's symbols.
    for lib in LIBS {
        if !location.libs.iter().any(|l| l == lib) {
            location.libs.push(lib.to_string());
        }
    }
    Ok(location)
}
