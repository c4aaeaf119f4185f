//! Packaging check: the vendored Embree bindings must describe the ABI of the installed Embree
//! headers (version major/minor and the two layout macros in `rtcore_config.h`). Uses the same
//! parser as the build script, which refuses to build on a mismatch.

#[allow(dead_code)]
#[path = "../build-support/embree.rs"]
mod build_embree;

use build_embree::{parse_defines, EmbreeConfig, VENDORED_BINDINGS};
use std::path::{Path, PathBuf};

fn installed_config_header() -> PathBuf {
    let candidates =
        std::env::var_os("EMBREE_DIR").map(|d| vec![Path::new(&d).join("include/embree3")]).unwrap_or_else(
            || vec![PathBuf::from("/usr/include/embree3"), PathBuf::from("/usr/local/include/embree3")],
        );
    candidates
        .into_iter()
        .map(|d| d.join("rtcore_config.h"))
        .find(|p| p.is_file())
        .expect("rtcore_config.h not found (install libembree-dev or set EMBREE_DIR)")
}

fn vendored_text() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(VENDORED_BINDINGS);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn vendored_stamp_matches_installed_rtcore_config() {
    let header = installed_config_header();
    let installed = EmbreeConfig::from_config_header(&std::fs::read_to_string(&header).unwrap()).unwrap();
    let vendored = EmbreeConfig::from_stamp(&vendored_text()).unwrap();
    let differences = vendored.abi_differences(&installed);
    assert!(differences.is_empty(), "vendored bindings vs {}: {differences:#?}", header.display());
    assert_eq!(vendored.version_major, 3);
}

#[test]
fn stamp_agrees_with_the_constants_bindgen_emitted() {
    // The stamp is written from rtcore_config.h, the constants by bindgen from the same headers; if
    // someone edits one by hand the two drift apart.
    let text = vendored_text();
    let stamp = EmbreeConfig::from_stamp(&text).unwrap();
    let constant = |name: &str| -> u32 {
        let prefix = format!("pub const {name}: u32 = ");
        let line = text
            .lines()
            .find_map(|l| l.strip_prefix(prefix.as_str()))
            .unwrap_or_else(|| panic!("{name} missing from the bindings"));
        line.trim_end_matches(';').parse().unwrap()
    };
    assert_eq!(constant("RTC_VERSION"), stamp.version);
    assert_eq!(constant("RTC_VERSION_MAJOR"), stamp.version_major);
    assert_eq!(constant("RTC_VERSION_MINOR"), stamp.version_minor);
    assert_eq!(constant("RTC_MAX_INSTANCE_LEVEL_COUNT"), stamp.max_instance_level_count);
    assert_eq!(constant("RTC_MIN_WIDTH"), stamp.min_width);
}

#[test]
fn config_parser_follows_macro_aliases_and_reports_each_difference() {
    let text = "#define RTC_VERSION_MAJOR 3\n#define RTC_VERSION_MINOR 12\n#define RTC_VERSION_PATCH 0\n\
                #define RTC_VERSION 31200\n#define RTC_VERSION_STRING \"3.12.0\"\n\
                #define RTC_MAX_INSTANCE_LEVEL_COUNT 2\n#define EMBREE_MIN_WIDTH 1\n\
                #define RTC_MIN_WIDTH EMBREE_MIN_WIDTH\n#  define RTC_NAMESPACE_USE\n";
    assert_eq!(parse_defines(text)["RTC_MIN_WIDTH"], "EMBREE_MIN_WIDTH");
    let other = EmbreeConfig::from_config_header(text).unwrap();
    assert_eq!(other.min_width, 1);
    assert_eq!(other.version_string, "3.12.0");

    let vendored = EmbreeConfig::from_stamp(&vendored_text()).unwrap();
    let differences = vendored.abi_differences(&other);
    assert_eq!(differences.len(), 3, "{differences:#?}");
    assert!(differences[0].contains("major.minor"));
    assert!(differences[1].contains("RTC_MAX_INSTANCE_LEVEL_COUNT"));
    assert!(differences[2].contains("RTC_MIN_WIDTH"));

    // A patch release alone keeps the ABI.
    let patched = EmbreeConfig {
        version_patch: vendored.version_patch + 1,
        version: vendored.version + 1,
        ..vendored.clone()
    };
    assert!(vendored.abi_differences(&patched).is_empty());
}

#[test]
fn stamp_round_trips_and_missing_stamp_is_an_error() {
    let vendored = EmbreeConfig::from_stamp(&vendored_text()).unwrap();
    let written = vendored.stamp(Path::new("/x/rtcore.h"), "test");
    assert_eq!(EmbreeConfig::from_stamp(&written).unwrap(), vendored);

    let err = EmbreeConfig::from_stamp("pub const RTC_VERSION: u32 = 31305;\n").unwrap_err();
    assert!(err.contains("stamp"), "{err}");
    let missing_key = written.replace("// RTC_MIN_WIDTH = 0\n", "");
    let err = EmbreeConfig::from_stamp(&missing_key).unwrap_err();
    assert!(err.contains("RTC_MIN_WIDTH"), "{err}");
}

/// The Embree 4 bindings (`--features embree4`) are stamped like the Embree 3 ones, from Embree 4
/// headers, and the stamp agrees with the constants bindgen emitted; the API names the Embree 4
/// compatibility layer translates exist in them with their Embree 4 shapes.
#[test]
fn embree4_bindings_are_stamped_and_have_the_embree4_api() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(build_embree::VENDORED_BINDINGS_4);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let stamp = EmbreeConfig::from_stamp(&text).unwrap();
    assert_eq!(stamp.version_major, 4);
    assert!(text.contains(&format!("pub const RTC_VERSION: u32 = {};", stamp.version)));
    assert!(text.contains(&format!(
        "pub const RTC_MAX_INSTANCE_LEVEL_COUNT: u32 = {};",
        stamp.max_instance_level_count
    )));
    for item in
        ["pub struct RTCIntersectArguments", "pub struct RTCOccludedArguments", "RTC_RAY_QUERY_FLAG_COHERENT"]
    {
        assert!(text.contains(item), "{item} missing");
    }
    // Embree 4 dropped the context and the stream calls.
    assert!(!text.contains("pub struct RTCIntersectContext") && !text.contains("rtcIntersect1M"));
    let compact: String = text.split_whitespace().collect::<Vec<_>>().join(" ");
    assert!(compact.contains(
        "pub fn rtcIntersect1(scene: RTCScene, rayhit: *mut RTCRayHit, args: *mut RTCIntersectArguments)"
    ));
}
