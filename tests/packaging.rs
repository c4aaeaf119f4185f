//! What a distribution package ships besides the binary: man pages and completions generated from
//! the clap definition, the `--version` report used in bug reports, and the cargo-deb asset list
//! in Cargo.toml agreeing with what `hslt generate-assets` writes.

use hslt::cli::assets;
use std::path::Path;
use std::process::Command;

fn hslt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hslt"))
}

fn visible_subcommands() -> Vec<String> {
    use clap::CommandFactory;
    hslt::cli::Cli::command()
        .get_subcommands()
        .filter(|s| !s.is_hide_set())
        .map(|s| s.get_name().to_string())
        .collect()
}

#[test]
fn man_page_names_every_subcommand_and_each_has_its_own_page() {
    let cmd = assets::command();
    let page = String::from_utf8(assets::man_page(&cmd).unwrap()).unwrap();
    assert!(page.starts_with(".ie") || page.starts_with(".TH"), "not roff: {page:.80}");
    assert!(page.contains(".SH SYNOPSIS") && page.contains(".SH SUBCOMMANDS"));
    let subcommands = visible_subcommands();
    assert!(subcommands.len() >= 3, "{subcommands:?}");
    let all = assets::assets().unwrap();
    for name in &subcommands {
        // roff escapes every '-' as '\-', including those inside hyphenated subcommand names.
        let escaped = name.replace('-', "\\-");
        assert!(page.contains(&format!("hslt\\-{escaped}")), "hslt.1 does not mention subcommand {name}");
        let sub_page = all
            .iter()
            .find(|a| a.file_name == format!("hslt-{name}.1"))
            .unwrap_or_else(|| panic!("no page for {name}"));
        let text = String::from_utf8_lossy(&sub_page.contents);
        assert!(text.contains(".SH OPTIONS"), "hslt-{name}.1 lists no options");
    }
    // The render page documents each of its long options.
    let render = all.iter().find(|a| a.file_name == "hslt-render.1").unwrap();
    let render = String::from_utf8_lossy(&render.contents);
    for long in ["output", "spp", "threads", "seed", "max\\-depth"] {
        assert!(render.contains(&format!("\\-\\-{long}")), "--{long} missing");
    }
}

#[test]
fn assets_are_reproducible() {
    let first = assets::assets().unwrap();
    let second = assets::assets().unwrap();
    assert_eq!(first, second);
    let page = String::from_utf8(first[0].contents.clone()).unwrap();
    let title = page.lines().find(|l| l.starts_with(".TH")).unwrap();
    assert!(title.contains(env!("CARGO_PKG_VERSION")), "{title}");
    // No generation date: the page must not change from one day to the next.
    let year_like = title.split(|c: char| !c.is_ascii_digit()).any(|w| w.len() == 4 && w.starts_with("20"));
    assert!(!year_like, "{title}");
}

#[test]
fn completions_cover_every_subcommand() {
    for (shell, file_name) in assets::SHELLS {
        let script = String::from_utf8(assets::completion(shell)).unwrap();
        for name in visible_subcommands() {
            assert!(script.contains(&name), "{file_name} lacks {name}");
        }
        // fish spells options `-l spp`, the others `--spp`.
        assert!(script.contains("spp"), "{file_name} lacks render's options");
    }
    let bash = assets::completion(clap_complete::Shell::Bash);
    if let Ok(out) =
        Command::new("bash").arg("-n").stdin(std::process::Stdio::piped()).arg("/dev/stdin").spawn().and_then(
            |mut child| {
                use std::io::Write;
                child.stdin.take().unwrap().write_all(&bash)?;
                child.wait_with_output()
            },
        )
    {
        assert!(out.status.success(), "bash -n rejects the bash completion");
    }
}

#[test]
fn generate_assets_writes_every_file_the_deb_metadata_lists() {
    let dir = std::env::temp_dir().join(format!("hslt-packaging-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = hslt().arg("generate-assets").arg(&dir).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml")).unwrap();
    let listed: Vec<&str> = manifest
        .lines()
        .filter_map(|l| l.trim().strip_prefix("[\"target/assets/"))
        .filter_map(|l| l.split('"').next())
        .collect();
    assert!(listed.len() >= 4, "asset lines not found: {listed:?}");
    for name in listed {
        if name == "libhslt_oiio.so" && !cfg!(feature = "oiio") {
            continue;
        }
        if let Some(ext) = name.strip_prefix('*') {
            let matching = std::fs::read_dir(&dir)
                .unwrap()
                .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().ends_with(ext))
                .count();
            // hslt.1 and one page per subcommand.
            assert_eq!(matching, 1 + visible_subcommands().len(), "{name}");
        } else {
            let path = dir.join(name);
            assert!(
                std::fs::metadata(&path).is_ok_and(|m| m.len() > 0),
                "Cargo.toml ships target/assets/{name}, which generate-assets did not write"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn long_version_names_the_loaded_libraries_and_features() {
    let out = hslt().arg("--version").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with(&format!("hslt {}\n", env!("CARGO_PKG_VERSION"))), "{text}");
    let embree = hslt::accel::embree_version();
    assert!(embree.starts_with("3."), "Embree did not start: {embree}");
    assert!(text.contains(&format!("Embree {embree}")), "{text}");
    match hslt::image::oiio_version() {
        Some(v) => assert!(text.contains(&format!("OpenImageIO {v}")), "{text}"),
        None => assert!(text.contains("OpenImageIO not built in"), "{text}"),
    }
    let features = text
        .lines()
        .find_map(|l| l.strip_prefix("features: "))
        .unwrap_or_else(|| panic!("no features line: {text}"));
    assert_eq!(features.split(", ").any(|f| f == "oiio"), cfg!(feature = "oiio"), "{text}");
    assert_eq!(features.split(", ").any(|f| f == "bindgen"), cfg!(feature = "bindgen"), "{text}");
}

#[test]
fn short_version_stays_one_line_and_subcommands_still_parse() {
    let out = hslt().arg("-V").output().unwrap();
    assert!(out.status.success());
    assert_eq!(String::from_utf8(out.stdout).unwrap(), format!("hslt {}\n", env!("CARGO_PKG_VERSION")));
    // The two-pass parse must not change ordinary errors: an unknown flag is still exit code 2.
    let out = hslt().args(["render", "--no-such-flag"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--no-such-flag"));
}
