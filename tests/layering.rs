//! The architecture stays as docs/architecture.md draws it: every top-level module of `src/` sits in
//! exactly one layer of the page's table and imports (`crate::…`) only modules of lower layers, so the
//! modules form no import cycle; and no file in `src/` passes 600 lines without saying why at its top.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const MAX_LINES: usize = 600;
const LENGTH_REASON: &str = "//! Over 600 lines because";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Module name → layer, from the table under "## Layers" in docs/architecture.md.
fn documented_layers() -> BTreeMap<String, u32> {
    let page = std::fs::read_to_string(root().join("docs/architecture.md")).expect("docs/architecture.md");
    let section = page.split("## Layers").nth(1).expect("docs/architecture.md has a '## Layers' section");
    let section = section.split("\n## ").next().unwrap();
    let mut layers = BTreeMap::new();
    for line in section.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        // "| 3 | `scene` | role |" splits into ["", "3", "`scene`", "role", ""].
        let Some(layer) = cells.get(1).and_then(|c| c.parse::<u32>().ok()) else { continue };
        for module in cells[2].split('`').skip(1).step_by(2) {
            let earlier = layers.insert(module.to_string(), layer);
            assert!(earlier.is_none(), "docs/architecture.md lists `{module}` twice");
        }
    }
    assert!(layers.len() > 5, "could not read the layer table of docs/architecture.md");
    layers
}

/// Top-level modules of the library: `src/<name>/` folders and `src/<name>.rs` files.
fn source_modules() -> Vec<String> {
    let mut modules = Vec::new();
    for entry in std::fs::read_dir(root().join("src")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        if path.is_dir() || (path.extension().is_some_and(|e| e == "rs") && name != "lib" && name != "main") {
            modules.push(name);
        }
    }
    modules.sort();
    modules
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The source with comments blanked out (string and char literals kept), so that `crate::` in a doc
/// comment is not taken for an import. Line breaks stay, so line numbers still match.
fn strip_comments(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'/' if b.get(i + 1) == Some(&b'/') => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            b'/' if b.get(i + 1) == Some(&b'*') => {
                let mut depth = 0;
                while i < b.len() {
                    if b[i..].starts_with(b"/*") {
                        depth += 1;
                        i += 2;
                    } else if b[i..].starts_with(b"*/") {
                        depth -= 1;
                        i += 2;
                        if depth == 0 {
                            break;
                        }
                    } else {
                        if b[i] == b'\n' {
                            out.push('\n');
                        }
                        i += 1;
                    }
                }
            }
            b'"' => {
                let start = i;
                i += 1;
                while i < b.len() && b[i] != b'"' {
                    i += if b[i] == b'\\' { 2 } else { 1 };
                }
                i = (i + 1).min(b.len());
                out.push_str(&src[start..i]);
            }
            // A char literal ('x', '\n', '"'); anything else after a quote is a lifetime.
            b'\'' if b.get(i + 2) == Some(&b'\'') => {
                out.push_str(&src[i..i + 3]);
                i += 3;
            }
            b'\'' if b.get(i + 1) == Some(&b'\\') => {
                let end = src[i + 2..].find('\'').map_or(b.len(), |e| i + 3 + e);
                out.push_str(&src[i..end]);
                i = end;
            }
            _ => {
                let ch = src[i..].chars().next().unwrap();
                out.push(ch);
                i += ch.len_utf8();
            }
        }
    }
    out
}

fn identifier_at(s: &str) -> &str {
    let end = s.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).unwrap_or(s.len());
    &s[..end]
}

/// Every top-level module named through `crate::`, with its line: `crate::scene::Scene` and each item
/// of `crate::{render::Film, scene}`.
fn crate_references(code: &str) -> Vec<(usize, String)> {
    let mut refs = Vec::new();
    for (at, _) in code.match_indices("crate::") {
        let line = code[..at].matches('\n').count() + 1;
        let rest = &code[at + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let (mut depth, mut item_start) = (0, true);
            for (k, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => item_start = true,
                    c if c.is_whitespace() => {}
                    _ if item_start && depth == 0 => {
                        item_start = false;
                        let name = identifier_at(&group[k..]);
                        if !name.is_empty() && name != "self" {
                            refs.push((line, name.to_string()));
                        }
                    }
                    _ => {}
                }
            }
        } else {
            let name = identifier_at(rest);
            if !name.is_empty() {
                refs.push((line, name.to_string()));
            }
        }
    }
    refs
}

/// The top-level module a file of `src/` belongs to.
fn module_of(file: &Path) -> String {
    let rel = file.strip_prefix(root().join("src")).unwrap();
    let first = rel.components().next().unwrap().as_os_str().to_string_lossy().to_string();
    first.strip_suffix(".rs").unwrap_or(&first).to_string()
}

#[test]
fn the_scanner_finds_imports_and_skips_comments() {
    let code = strip_comments(
        "use crate::{render::{Film, Splat}, scene, self};\n// crate::cli in a comment\n\
         let s = \"// not a comment\"; let q = '\"'; fn f<'a>() {}\n/* crate::bench */ let x = crate::path::f();",
    );
    let names: Vec<(usize, String)> = crate_references(&code);
    assert_eq!(
        names,
        vec![(1, "render".to_string()), (1, "scene".to_string()), (4, "path".to_string())],
        "{code}"
    );
}

#[test]
fn every_module_has_one_layer_in_docs_architecture() {
    let layers = documented_layers();
    let modules = source_modules();
    let missing: Vec<&String> = modules.iter().filter(|m| !layers.contains_key(*m)).collect();
    let stale: Vec<&String> = layers.keys().filter(|m| !modules.contains(m)).collect();
    assert!(
        missing.is_empty(),
        "modules of src/ missing from docs/architecture.md's layer table: {missing:?}"
    );
    assert!(stale.is_empty(), "docs/architecture.md lists modules that src/ does not have: {stale:?}");
}

#[test]
fn modules_import_only_lower_layers() {
    let layers = documented_layers();
    let mut files = Vec::new();
    rust_files(&root().join("src"), &mut files);
    files.sort();
    let mut violations = Vec::new();
    let mut checked = 0;
    for file in &files {
        let module = module_of(file);
        let Some(&layer) = layers.get(&module) else { continue };
        let code = strip_comments(&std::fs::read_to_string(file).unwrap());
        for (line, target) in crate_references(&code) {
            checked += 1;
            if target == module {
                continue;
            }
            // Macros and items of the crate root (lib.rs) are not modules.
            let Some(&target_layer) = layers.get(&target) else { continue };
            if target_layer >= layer {
                violations.push(format!(
                    "{}:{line}: `{module}` (layer {layer}) imports `{target}` (layer {target_layer})",
                    file.strip_prefix(root()).unwrap().display()
                ));
            }
        }
    }
    assert!(checked > 300, "only {checked} crate:: references found: the scanner is broken");
    assert!(
        violations.is_empty(),
        "imports against docs/architecture.md's layers (a module may use only lower layers):\n{}",
        violations.join("\n")
    );
}

#[test]
fn long_files_say_why_at_their_top() {
    let mut files = Vec::new();
    rust_files(&root().join("src"), &mut files);
    let mut unexplained = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap();
        let lines = text.lines().count();
        let head_has_reason =
            text.lines().take_while(|l| l.starts_with("//!")).any(|l| l.starts_with(LENGTH_REASON));
        if lines > MAX_LINES && !head_has_reason {
            unexplained.push(format!("{} ({lines} lines)", file.strip_prefix(root()).unwrap().display()));
        }
    }
    assert!(
        unexplained.is_empty(),
        "files over {MAX_LINES} lines without a '{LENGTH_REASON} …' line in their module doc: {unexplained:?}"
    );
}
