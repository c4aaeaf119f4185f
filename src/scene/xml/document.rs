//! Scene files as documents: the checks every file goes through before and while roxmltree parses it
//! (memory, element nesting), line and column numbers for messages, and `<include>`, which parses
//! another file in place.

use super::{at, XmlParser};
use crate::props::{SceneError, SrcLoc};
use crate::scene::Props;
use roxmltree::{Document, Node};
use std::cell::Cell;
use std::path::Path;

/// The checks every scene file goes through (memory, nesting) and roxmltree's parse.
pub(super) fn parse_document<'t>(text: &'t str, path: &Path) -> Result<Document<'t>, SceneError> {
    check_parse_fits(text.len() as u64, PARSE_BYTES_PER_FILE_BYTE, path)?;
    let base_loc = SrcLoc::new(path, 0, 0);
    if let Some(offset) = first_element_too_deep(text) {
        let (line, col) = LineIndex::new(text).line_and_column(offset);
        return Err(SceneError::new(
            at(&base_loc, line, col),
            None,
            format!("elements nested more than {MAX_NESTING} deep (a scene needs a handful of levels)"),
        ));
    }
    // roxmltree refuses DTDs (and therefore entity expansion) by default, which is what we want.
    Document::parse(text).map_err(|e| {
        let pos = e.pos();
        SceneError::new(at(&base_loc, pos.row, pos.col), None, format!("malformed XML: {e}"))
    })
}

/// How deep `<include>`s may nest: each included file may nest `MAX_NESTING` elements again, and the
/// descent recurses through all of them.
pub const MAX_INCLUDE_DEPTH: usize = 8;

/// Peak memory of parsing per byte of scene XML (roxmltree's nodes and attributes, then our `Props`):
/// 1 M small elements in 79 MB peaked at 1.75 GB, 22 bytes per byte; 24 leaves a margin.
pub(super) const PARSE_BYTES_PER_FILE_BYTE: u64 = 24;

/// A scene file too large to parse in the memory left is an error naming it, not an aborted
/// allocation half-way through (a file of millions of elements, #33).
pub(super) fn check_parse_fits(file_bytes: u64, bytes_per_byte: u64, path: &Path) -> Result<(), SceneError> {
    let what = format!("parsing this scene file of {}", crate::resources::human_size(file_bytes));
    crate::resources::check_fits(file_bytes.saturating_mul(bytes_per_byte), &what)
        .map_err(|e| SceneError::file(path, e))
}

/// Deepest element nesting a scene may have. Real scenes need a handful of levels (scene, shape, bsdf,
/// twosided's inner bsdf, texture); the limit turns a runaway or hostile file into an error instead of
/// a stack overflow: roxmltree's tokenizer recurses once per level (its issue #154), and so do the
/// descent below and the drop of the nested `Props`.
pub const MAX_NESTING: usize = 100;

/// Byte offset of the first start tag nested deeper than `MAX_NESTING`, by a scan of the tags alone, so
/// that roxmltree never sees such a document. Comments, CDATA, processing instructions and
/// declarations are skipped and quoted attribute values may hold `>`; malformed input is left to
/// roxmltree, which reports it properly (this scan only has to count right on well-formed nesting).
fn first_element_too_deep(text: &str) -> Option<usize> {
    let b = text.as_bytes();
    let skip_past = |from: usize, end: &[u8]| {
        b[from..].windows(end.len()).position(|w| w == end).map_or(b.len(), |k| from + k + end.len())
    };
    let mut depth = 0usize;
    let mut i = 0;
    while let Some(k) = b[i..].iter().position(|&c| c == b'<').map(|k| i + k) {
        let rest = &b[k..];
        i = if rest.starts_with(b"<!--") {
            skip_past(k + 4, b"-->")
        } else if rest.starts_with(b"<![CDATA[") {
            skip_past(k + 9, b"]]>")
        } else if rest.starts_with(b"<?") {
            skip_past(k + 2, b"?>")
        } else if rest.starts_with(b"<!") {
            skip_past(k + 2, b">")
        } else if rest.starts_with(b"</") {
            depth = depth.saturating_sub(1);
            skip_past(k + 2, b">")
        } else {
            let mut j = k + 1;
            let mut quote = None;
            while j < b.len() {
                match (quote, b[j]) {
                    (Some(q), c) if c == q => quote = None,
                    (None, c @ (b'"' | b'\'')) => quote = Some(c),
                    (None, b'>') => break,
                    _ => {}
                }
                j += 1;
            }
            // An empty-element tag sits one level down too, it just opens nothing below it.
            if depth + 1 > MAX_NESTING {
                return Some(k);
            }
            if b[j - 1] != b'/' {
                depth += 1;
            }
            j + 1
        };
        if i >= b.len() {
            break;
        }
    }
    None
}

/// Line and column of byte offsets, in time independent of the file's length: roxmltree's own
/// `text_pos_at` scans from the start of the document at every call, which made a scene of 40 000
/// elements take 25 s to load (quadratic) before this index replaced it.
pub(super) struct LineIndex<'t> {
    text: &'t str,
    /// Byte offset where each line starts.
    starts: Vec<usize>,
    /// The last position asked for (offset, column): elements are visited in document order, so the
    /// next one usually lies further along the same line, which matters when a whole file is one line.
    last: Cell<(usize, u32)>,
}

impl<'t> LineIndex<'t> {
    pub(super) fn new(text: &'t str) -> Self {
        let starts = std::iter::once(0).chain(text.match_indices('\n').map(|(i, _)| i + 1)).collect();
        LineIndex { text, starts, last: Cell::new((0, 1)) }
    }

    /// 1-based line and column (in characters) of a byte offset.
    pub(super) fn line_and_column(&self, offset: usize) -> (u32, u32) {
        let offset = offset.min(self.text.len());
        let line = self.starts.partition_point(|&s| s <= offset) - 1;
        let line_start = self.starts[line];
        let (last_offset, last_col) = self.last.get();
        let (from, col_before) = if last_offset >= line_start && last_offset <= offset {
            (last_offset, last_col)
        } else {
            (line_start, 1)
        };
        let col = col_before + self.text[from..offset].chars().count() as u32;
        self.last.set((offset, col));
        (line as u32 + 1, col)
    }
}

impl<'i> XmlParser<'i> {
    /// `<include filename=...>`: the children of the named file's `<scene>` are parsed here, in
    /// place, as Mitsuba does, sharing ids and parameters with the including file. The file name is
    /// relative to the including file; the chain of open files catches cycles. File names inside
    /// the included file (meshes, textures) still resolve against the scene's directory, as
    /// Mitsuba's file resolver does.
    pub(super) fn include(
        &mut self,
        node: Node<'_, 'i>,
        filename: &str,
        parent: &mut Props,
        parent_plugin_type: Option<&str>,
        top_level: bool,
    ) -> Result<(), SceneError> {
        let including_dir = self.base_loc.file.parent().unwrap_or(Path::new("")).to_path_buf();
        let path = including_dir.join(filename);
        let canonical = path
            .canonicalize()
            .map_err(|e| self.err(node, format!("cannot open the included file {}: {e}", path.display())))?;
        if let Some(first) = self.includes.iter().position(|(p, _)| *p == canonical) {
            let chain: Vec<String> = self.includes[first..]
                .iter()
                .map(|(_, shown)| shown)
                .chain([&path])
                .map(|p| p.display().to_string())
                .collect();
            return Err(self.err(node, format!("<include> cycle: {}", chain.join(" includes "))));
        }
        if self.includes.len() > MAX_INCLUDE_DEPTH {
            return Err(self.err(node, format!("<include>s nested more than {MAX_INCLUDE_DEPTH} deep")));
        }
        let here = self.loc_of(node);
        let in_included = |mut e: SceneError| {
            e.message += &format!(" (in a file included at {here})");
            e
        };
        // A regular file only: reading /dev/zero or a FIFO would never end.
        let meta = std::fs::metadata(&canonical).ok().filter(|m| m.is_file()).ok_or_else(|| {
            self.err(node, format!("the included file {} is not a regular file", path.display()))
        })?;
        check_parse_fits(meta.len(), PARSE_BYTES_PER_FILE_BYTE + 1, &path).map_err(in_included)?;
        let text = std::fs::read_to_string(&path)
            .map_err(|e| self.err(node, format!("cannot read the included file {}: {e}", path.display())))?;
        crate::resources::note_input_file(&path);
        let doc = parse_document(&text, &path).map_err(in_included)?;
        let mut includes = std::mem::take(&mut self.includes);
        includes.push((canonical, path.clone()));
        let mut sub = XmlParser {
            lines: LineIndex::new(&text),
            base_loc: SrcLoc::new(&path, 0, 0),
            params: std::mem::take(&mut self.params),
            ids: std::mem::take(&mut self.ids),
            includes,
        };
        let root = doc.root_element();
        let result = sub.check_scene_root(root).and_then(|()| {
            root.children()
                .try_for_each(|child| sub.parse_child(child, parent, parent_plugin_type, top_level))
        });
        self.params = sub.params;
        self.ids = sub.ids;
        self.includes = sub.includes;
        self.includes.pop();
        result.map_err(in_included)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_index_agrees_with_counting_from_the_start_in_any_order() {
        let text = "<scene>\n  <bsdf type=\"diffuse\"/><a/>\n\nαβ<b/> <c/>\n<d/>";
        let naive = |offset: usize| {
            let before = &text[..offset];
            let line = before.matches('\n').count() + 1;
            let col = before.rsplit('\n').next().unwrap().chars().count() + 1;
            (line as u32, col as u32)
        };
        let index = LineIndex::new(text);
        let offsets: Vec<usize> = (0..=text.len()).filter(|&i| text.is_char_boundary(i)).collect();
        // Forwards (the cached path), backwards and jumping about (the cache must not be trusted).
        for &o in offsets.iter().chain(offsets.iter().rev()).chain(offsets.iter().step_by(3).rev()) {
            assert_eq!(index.line_and_column(o), naive(o), "offset {o}");
        }
    }
}
