//! Locates the system Embree 3 (or, with the `embree4` feature, Embree 4) through EMBREE_DIR, then
//! pkg-config, then standard paths, links it, and makes sure the Rust bindings describe the same ABI
//! as the installed headers: either by comparing the vendored bindings' stamp with `rtcore_config.h`,
//! or (feature `bindgen`) by regenerating them.

use std::collections::BTreeMap;
use std::env;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Vendored bindings, relative to the crate root (Embree 3; Embree 4's are `VENDORED_BINDINGS_4`).
pub const VENDORED_BINDINGS: &str = "vendor-bindings/embree3.rs";
pub const VENDORED_BINDINGS_4: &str = "vendor-bindings/embree4.rs";
/// The `cfg` the Rust side checks to include `$OUT_DIR/embree3.rs` instead of the vendored file.
pub const BINDGEN_CFG: &str = "hslt_embree_bindgen";
const STAMP_BEGIN: &str = "// hslt-embree-bindings-stamp-begin";
const STAMP_END: &str = "// hslt-embree-bindings-stamp-end";
const DEBIAN_PACKAGE: &str = "libembree-dev";

/// The Embree major version this build targets: 4 with the `embree4` feature, else 3. It names the
/// headers (include/embree<major>), the library (libembree<major>) and the vendored bindings.
fn major() -> u32 {
    if env::var_os("CARGO_FEATURE_EMBREE4").is_some() {
        4
    } else {
        3
    }
}

pub fn configure() {
    let major = major();
    let vendored_rel = if major == 4 { VENDORED_BINDINGS_4 } else { VENDORED_BINDINGS };
    println!("cargo:rerun-if-env-changed=EMBREE_DIR");
    println!("cargo:rerun-if-env-changed=PKG_CONFIG_PATH");
    println!("cargo:rerun-if-changed={vendored_rel}");
    println!("cargo::rustc-check-cfg=cfg({BINDGEN_CFG})");

    let install = match locate(major) {
        Ok(install) => install,
        // Embree 4 is for distributions after bookworm; on a machine without it the crate must still
        // type-check (CI runs `cargo check --features embree4` on bookworm), so only linking fails.
        Err(msg) if major == 4 && env::var_os("CARGO_FEATURE_BINDGEN").is_none() => {
            println!("cargo:warning={msg} Checking against the vendored bindings; linking will fail.");
            println!("cargo:rustc-link-lib=embree4");
            return;
        }
        Err(msg) => fail(&msg),
    };
    let config_header = install.header_dir.join("rtcore_config.h");
    println!("cargo:rerun-if-changed={}", config_header.display());

    for dir in &install.lib_dirs {
        println!("cargo:rustc-link-search=native={}", dir.display());
        if install.add_rpath {
            // A private install is not on the loader's path; without this the tests would build but not start.
            println!("cargo:rustc-link-arg=-Wl,-rpath,{}", dir.display());
        }
    }
    println!("cargo:rustc-link-lib=embree{major}");

    let config_text = fs::read_to_string(&config_header).unwrap_or_else(|e| {
        fail(&format!(
            "cannot read {} (found Embree via {}): {e}",
            config_header.display(),
            install.found_via
        ))
    });
    let installed = EmbreeConfig::from_config_header(&config_text)
        .unwrap_or_else(|e| fail(&format!("{}: {e}", config_header.display())));

    if env::var_os("CARGO_FEATURE_BINDGEN").is_some() {
        generate_into_out_dir(&install, &installed);
        println!("cargo:rustc-cfg={BINDGEN_CFG}");
        return;
    }

    let manifest_dir = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    let vendored_path = manifest_dir.join(vendored_rel);
    let vendored_text = fs::read_to_string(&vendored_path)
        .unwrap_or_else(|e| fail(&format!("cannot read {}: {e}", vendored_path.display())));
    let vendored = EmbreeConfig::from_stamp(&vendored_text)
        .unwrap_or_else(|e| fail(&format!("{}: {e}", vendored_path.display())));
    let differences = vendored.abi_differences(&installed);
    if !differences.is_empty() {
        let mut msg = format!(
            "the vendored Embree bindings do not match the installed Embree headers.\n  \
             vendored:  {} (generated for Embree {})\n  installed: {} (Embree {}, found via {})\n\
             Differences that change the ABI:\n",
            vendored_path.display(),
            vendored.version_string,
            config_header.display(),
            installed.version_string,
            install.found_via,
        );
        for d in &differences {
            let _ = writeln!(msg, "  - {d}");
        }
        msg.push_str(
            "Build with `--features bindgen` to generate bindings from the installed headers \
             (needs libclang), or run scripts/regen-embree-bindings.sh to refresh the vendored file, \
             or point EMBREE_DIR at an Embree install that matches the vendored bindings.",
        );
        fail(&msg);
    }
}

/// Prints a build error and stops the build script. Cargo shows the stderr of a failed build script,
/// so the message reaches the user without a panic backtrace in the way.
fn fail(msg: &str) -> ! {
    eprintln!("\nerror: hslt build (Embree): {msg}\n");
    std::process::exit(1);
}

/// Where the Embree headers and library live.
pub struct EmbreeInstall {
    /// Directory holding `rtcore.h` and `rtcore_config.h` (normally `.../include/embree3`).
    pub header_dir: PathBuf,
    /// Extra linker search paths (empty for the toolchain's default paths).
    pub lib_dirs: Vec<PathBuf>,
    pub found_via: String,
    add_rpath: bool,
}

fn locate(major: u32) -> Result<EmbreeInstall, String> {
    if let Some(dir) = env::var_os("EMBREE_DIR") {
        // An explicit EMBREE_DIR that is wrong must not silently fall back to another install.
        return from_embree_dir(Path::new(&dir), major);
    }
    if let Some(found) = from_pkg_config(major) {
        return Ok(found);
    }
    let (system, local) =
        (format!("/usr/include/embree{major}"), format!("/usr/local/include/embree{major}"));
    for (include, lib) in [(system.as_str(), None), (local.as_str(), Some("/usr/local/lib"))] {
        let header_dir = PathBuf::from(include);
        if header_dir.join("rtcore.h").is_file() {
            return Ok(EmbreeInstall {
                header_dir,
                lib_dirs: lib.map(PathBuf::from).into_iter().collect(),
                found_via: format!("system path {include}"),
                add_rpath: false,
            });
        }
    }
    Err(format!(
        "Embree {major} was not found. Install the package `{DEBIAN_PACKAGE}` (Embree {major}.x; \
         apt-get install {DEBIAN_PACKAGE}), or set EMBREE_DIR to an Embree {major} install prefix \
         containing include/embree{major}/rtcore.h and lib/libembree{major}.so. Searched: EMBREE_DIR \
         (unset), pkg-config `embree{major}`, /usr/include/embree{major}, /usr/local/include/embree{major}."
    ))
}

fn from_embree_dir(dir: &Path, major: u32) -> Result<EmbreeInstall, String> {
    let header_dir = dir.join("include").join(format!("embree{major}"));
    if !header_dir.join("rtcore.h").is_file() {
        return Err(format!(
            "EMBREE_DIR={} but {} does not exist; EMBREE_DIR must be an Embree {major} install prefix \
             (with include/embree{major}/ and lib/), or unset it to use the system package `{DEBIAN_PACKAGE}`.",
            dir.display(),
            header_dir.join("rtcore.h").display()
        ));
    }
    let lib_dirs: Vec<PathBuf> =
        ["lib", "lib64"].iter().map(|l| dir.join(l)).filter(|p| p.is_dir()).collect();
    if lib_dirs.is_empty() {
        return Err(format!(
            "EMBREE_DIR={} has include/embree{major} but neither lib/ nor lib64/",
            dir.display()
        ));
    }
    Ok(EmbreeInstall {
        header_dir,
        lib_dirs,
        found_via: format!("EMBREE_DIR={}", dir.display()),
        add_rpath: true,
    })
}

/// Debian ships no `embree3.pc`, so this usually finds nothing; source builds of Embree do install one.
fn from_pkg_config(major: u32) -> Option<EmbreeInstall> {
    let name = format!("embree{major}");
    let output =
        Command::new("pkg-config").args(["--cflags-only-I", "--libs-only-L", &name]).output().ok()?;
    if !output.status.success() {
        return None;
    }
    let flags = String::from_utf8_lossy(&output.stdout).into_owned();
    let mut header_dir = None;
    let mut lib_dirs = Vec::new();
    for flag in flags.split_whitespace() {
        if let Some(inc) = flag.strip_prefix("-I") {
            // The .pc file may name either the prefix's include/ or include/embree3 itself.
            for candidate in [PathBuf::from(inc).join(&name), PathBuf::from(inc)] {
                if header_dir.is_none() && candidate.join("rtcore.h").is_file() {
                    header_dir = Some(candidate);
                }
            }
        } else if let Some(lib) = flag.strip_prefix("-L") {
            lib_dirs.push(PathBuf::from(lib));
        }
    }
    let header_dir = header_dir.or_else(|| {
        // An empty -I list means the default include path.
        let default = PathBuf::from(format!("/usr/include/{name}"));
        default.join("rtcore.h").is_file().then_some(default)
    })?;
    Some(EmbreeInstall { header_dir, lib_dirs, found_via: format!("pkg-config {name}"), add_rpath: false })
}

/// The configuration macros that decide the layout of Embree's public structs
/// (`RTCHit::instID`, `RTCIntersectContext`) plus the version they came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EmbreeConfig {
    pub version_major: u32,
    pub version_minor: u32,
    pub version_patch: u32,
    pub version: u32,
    pub version_string: String,
    pub max_instance_level_count: u32,
    pub min_width: u32,
}

impl EmbreeConfig {
    /// Reads the `#define`s of an installed `rtcore_config.h`.
    pub fn from_config_header(text: &str) -> Result<EmbreeConfig, String> {
        let defines = parse_defines(text);
        Self::from_map(&defines, "rtcore_config.h")
    }

    /// Reads the stamp block that `stamp()` writes at the top of generated bindings.
    pub fn from_stamp(text: &str) -> Result<EmbreeConfig, String> {
        let mut map = BTreeMap::new();
        let mut inside = false;
        let mut closed = false;
        for line in text.lines() {
            let line = line.trim();
            if line == STAMP_BEGIN {
                inside = true;
            } else if line == STAMP_END {
                closed = inside;
                break;
            } else if inside {
                let body = line.trim_start_matches("//").trim();
                if let Some((k, v)) = body.split_once('=') {
                    map.insert(k.trim().to_string(), v.trim().to_string());
                }
            }
        }
        if !closed {
            return Err(format!(
                "no `{STAMP_BEGIN}` ... `{STAMP_END}` block; the bindings were not generated by \
                 build-support/embree.rs (see vendor-bindings/README.md)"
            ));
        }
        Self::from_map(&map, "bindings stamp")
    }

    fn from_map(map: &BTreeMap<String, String>, what: &str) -> Result<EmbreeConfig, String> {
        let number = |key: &str| -> Result<u32, String> {
            let raw = resolve(map, key).ok_or_else(|| format!("{what} does not define {key}"))?;
            raw.parse::<u32>().map_err(|_| format!("{what}: {key} is `{raw}`, expected an unsigned integer"))
        };
        let version_string = resolve(map, "RTC_VERSION_STRING")
            .ok_or_else(|| format!("{what} does not define RTC_VERSION_STRING"))?
            .trim_matches('"')
            .to_string();
        Ok(EmbreeConfig {
            version_major: number("RTC_VERSION_MAJOR")?,
            version_minor: number("RTC_VERSION_MINOR")?,
            version_patch: number("RTC_VERSION_PATCH")?,
            version: number("RTC_VERSION")?,
            version_string,
            max_instance_level_count: number("RTC_MAX_INSTANCE_LEVEL_COUNT")?,
            min_width: number("RTC_MIN_WIDTH")?,
        })
    }

    /// Human-readable list of what differs in a way that matters for the bindings. Patch releases keep
    /// the ABI, so only major/minor version and the two layout macros count.
    pub fn abi_differences(&self, installed: &EmbreeConfig) -> Vec<String> {
        let mut out = Vec::new();
        if (self.version_major, self.version_minor) != (installed.version_major, installed.version_minor) {
            out.push(format!(
                "RTC_VERSION major.minor: bindings {}.{}, installed {}.{} (functions and structs may differ)",
                self.version_major, self.version_minor, installed.version_major, installed.version_minor
            ));
        }
        if self.max_instance_level_count != installed.max_instance_level_count {
            out.push(format!(
                "RTC_MAX_INSTANCE_LEVEL_COUNT: bindings {}, installed {} (changes the size of RTCHit, \
                 RTCIntersectContext and every ray-hit packet)",
                self.max_instance_level_count, installed.max_instance_level_count
            ));
        }
        if self.min_width != installed.min_width {
            out.push(format!(
                "RTC_MIN_WIDTH: bindings {}, installed {} (changes the size of RTCIntersectContext)",
                self.min_width, installed.min_width
            ));
        }
        out
    }

    /// The machine-readable comment block written at the top of generated bindings.
    #[cfg_attr(not(feature = "bindgen"), allow(dead_code))]
    pub fn stamp(&self, source_header: &Path, generator: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "// Embree {} bindings generated by bindgen via build-support/embree.rs. Do not edit by hand;\n\
             // regenerate with scripts/regen-embree-bindings.sh (see vendor-bindings/README.md).",
            self.version_major
        );
        let _ = writeln!(s, "{STAMP_BEGIN}");
        let _ = writeln!(s, "// RTC_VERSION_MAJOR = {}", self.version_major);
        let _ = writeln!(s, "// RTC_VERSION_MINOR = {}", self.version_minor);
        let _ = writeln!(s, "// RTC_VERSION_PATCH = {}", self.version_patch);
        let _ = writeln!(s, "// RTC_VERSION = {}", self.version);
        let _ = writeln!(s, "// RTC_VERSION_STRING = {}", self.version_string);
        let _ = writeln!(s, "// RTC_MAX_INSTANCE_LEVEL_COUNT = {}", self.max_instance_level_count);
        let _ = writeln!(s, "// RTC_MIN_WIDTH = {}", self.min_width);
        let _ = writeln!(s, "// source_header = {}", source_header.display());
        let _ = writeln!(s, "// generator = {generator}");
        let _ = writeln!(s, "{STAMP_END}");
        s
    }
}

/// `#define NAME VALUE` lines of a header, ignoring function-like macros and empty defines.
pub fn parse_defines(text: &str) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for line in text.lines() {
        let Some(rest) = line.trim_start().strip_prefix('#') else {
            continue;
        };
        let Some(rest) = rest.trim_start().strip_prefix("define") else {
            continue;
        };
        let mut parts = rest.trim().splitn(2, char::is_whitespace);
        let (Some(name), Some(value)) = (parts.next(), parts.next()) else {
            continue;
        };
        if name.contains('(') || name.is_empty() {
            continue;
        }
        out.insert(name.to_string(), value.trim().to_string());
    }
    out
}

/// Follows `#define A B` / `#define B 0` chains (RTC_MIN_WIDTH is defined as EMBREE_MIN_WIDTH).
fn resolve<'a>(map: &'a BTreeMap<String, String>, key: &str) -> Option<&'a str> {
    let mut current = map.get(key)?.as_str();
    for _ in 0..8 {
        match map.get(current) {
            Some(next) => current = next.as_str(),
            None => return Some(current),
        }
    }
    None
}

// Only the build script itself runs bindgen; tests include this file for the parsers above and must
// not need the bindgen crate.
#[cfg(all(feature = "bindgen", not(test)))]
fn generate_into_out_dir(install: &EmbreeInstall, installed: &EmbreeConfig) {
    let header = install.header_dir.join("rtcore.h");
    let out_dir = PathBuf::from(env::var_os("OUT_DIR").unwrap_or_default());
    let clang = bindgen::clang_version();
    // Generate for the crate's MSRV so that vendored and regenerated output compile on the same
    // toolchains (newer targets switch to `unsafe extern` blocks, which 1.80 rejects).
    let msrv_minor = env::var("CARGO_PKG_RUST_VERSION")
        .ok()
        .and_then(|v| v.split('.').nth(1).and_then(|m| m.parse::<u64>().ok()))
        .unwrap_or(80);
    let rust_target = bindgen::RustTarget::stable(msrv_minor, 0)
        .unwrap_or_else(|e| fail(&format!("bindgen cannot target Rust 1.{msrv_minor}: {e}")));
    let bindings = bindgen::Builder::default()
        .rust_target(rust_target)
        .header(header.to_string_lossy())
        .allowlist_function("rtc.*")
        .allowlist_type("RTC.*")
        .allowlist_var("RTC.*")
        // Plain integer constants: Embree may hand back enum values we do not know about, which would be
        // undefined behaviour for a Rust enum.
        .default_enum_style(bindgen::EnumVariation::Consts)
        .prepend_enum_name(false)
        .derive_default(true)
        .derive_copy(true)
        .derive_debug(true)
        .layout_tests(true)
        .generate_comments(false)
        .parse_callbacks(Box::new(bindgen::CargoCallbacks::new()))
        .generate()
        .unwrap_or_else(|e| {
            fail(&format!(
                "bindgen failed on {} ({}): {e}. Is libclang installed (Debian: libclang-dev)?",
                header.display(),
                clang.full
            ))
        });
    let generator = format!("bindgen 0.71 crate, rust_target 1.{msrv_minor}, {}", clang.full);
    let text = format!("{}\n{}", installed.stamp(&header, &generator), bindings);
    let path = out_dir.join(format!("embree{}.rs", installed.version_major));
    fs::write(&path, text).unwrap_or_else(|e| fail(&format!("cannot write {}: {e}", path.display())));
}

#[cfg(not(all(feature = "bindgen", not(test))))]
fn generate_into_out_dir(_install: &EmbreeInstall, _installed: &EmbreeConfig) {
    fail(
        "CARGO_FEATURE_BINDGEN is set but this build script was compiled without the `bindgen` feature; \
         build with `cargo build --features bindgen`",
    );
}
