//! The entry points that coverage-guided fuzzing drives (fuzz/, `cargo afl`) and that
//! tests/fuzz_corpus.rs replays on the committed corpus: each takes arbitrary bytes as one kind of
//! input file and must return (an error is fine) without panicking, aborting or hanging.

use crate::accel::AccelKind;
use crate::scene::{LoadOptions, Scene};
use std::path::{Path, PathBuf};

/// The kinds of input file a user hands the renderer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Input {
    /// Scene XML, loaded and built into a scene (plugins, shapes, BVH).
    SceneXml,
    /// A Wavefront OBJ mesh referenced by a scene.
    Obj,
    /// A PLY mesh (ASCII or binary) referenced by a scene.
    Ply,
    /// An OpenEXR image (textures, references).
    Exr,
    /// A PNG image, read through OpenImageIO (textures).
    Png,
}

impl Input {
    pub const ALL: [Input; 5] = [Input::SceneXml, Input::Obj, Input::Ply, Input::Exr, Input::Png];

    /// The name of the fuzz target and of its corpus folder.
    pub fn name(self) -> &'static str {
        match self {
            Input::SceneXml => "scene_xml",
            Input::Obj => "obj",
            Input::Ply => "ply",
            Input::Exr => "exr",
            Input::Png => "png",
        }
    }

    pub fn parse(name: &str) -> Option<Input> {
        Input::ALL.into_iter().find(|i| i.name() == name)
    }
}

/// Feeds `data` to the loader of `input`; `Ok` if it was accepted, the loader's error otherwise.
/// Files go to a private temporary folder, since the loaders read paths. Scenes are built on Embree,
/// the default backend (the fuzzer's builds turn on obvhs's debug-only BVH validation, whose
/// absolute tolerance large meshes exceed; see Cargo.toml).
pub fn feed(input: Input, data: &[u8]) -> anyhow::Result<()> {
    feed_with(input, data, AccelKind::Embree)
}

/// As `feed`, with scenes built on the given ray-query backend.
pub fn feed_with(input: Input, data: &[u8], accel: AccelKind) -> anyhow::Result<()> {
    let dir = TempDir::new()?;
    let options = LoadOptions { defines: Vec::new(), accel };
    match input {
        Input::SceneXml => {
            // A file for `<include>` to find: the fuzzed scene may include it, or itself (a cycle).
            std::fs::write(dir.0.join("part.xml"), INCLUDED_PART)?;
            let text = String::from_utf8_lossy(data);
            Scene::load_str(&text, &dir.0.join("scene.xml"), &options).map(|_| ())
        }
        Input::Obj | Input::Ply => {
            let file = if input == Input::Obj { "mesh.obj" } else { "mesh.ply" };
            std::fs::write(dir.0.join(file), data)?;
            let scene = format!(
                "<scene version=\"3.0.0\"><sensor type=\"perspective\"><float name=\"fov\" value=\"45\"/><film type=\"hdrfilm\">\
                 <integer name=\"width\" value=\"4\"/><integer name=\"height\" value=\"4\"/></film></sensor>\
                 <shape type=\"{}\"><string name=\"filename\" value=\"{file}\"/></shape>\
                 <emitter type=\"constant\"/></scene>",
                &file[5..]
            );
            Scene::load_str(&scene, &dir.0.join("scene.xml"), &options).map(|_| ())
        }
        Input::Exr | Input::Png => {
            let path = dir.0.join(if input == Input::Exr { "image.exr" } else { "image.png" });
            std::fs::write(&path, data)?;
            crate::image::read_image(&path, true).map(|_| ())
        }
    }
}

/// The file next to a fuzzed scene that its `<include filename="part.xml"/>` reads.
const INCLUDED_PART: &str = r#"<scene version="3.0.0">
    <default name="part_reflectance" value="0.5"/>
    <bsdf type="diffuse" id="part"><rgb name="reflectance" value="$part_reflectance"/></bsdf>
    <shape type="rectangle"><ref id="part"/></shape>
</scene>"#;

/// A folder removed when dropped, unique per process and call.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> anyhow::Result<TempDir> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("hslt-fuzz-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        Ok(TempDir(dir))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The committed corpus and regression inputs of one target: `fuzz/corpus/<name>/*`.
pub fn corpus_dir(root: &Path, input: Input) -> PathBuf {
    root.join("fuzz/corpus").join(input.name())
}
