//! The fuzzing corpus as regression tests, on the stable toolchain and without AFL++: every seed of
//! fuzz/corpus/<target>/ and every crash a fuzzing run found (fuzz/regressions/<target>/, once fixed)
//! goes through the same entry point the fuzzer drives, and so do random mutations of the seeds (byte flips,
//! insertions, deletions, truncation, splices) — a quick mutation fuzzer that runs in every CI build.
//! None may panic; the loaders answer bad input with an error.

use hslt::accel::AccelKind;
use hslt::fuzzing::{corpus_dir, feed, feed_with, Input};
use proptest::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

fn corpus(input: Input) -> Vec<(String, Vec<u8>)> {
    let dir = corpus_dir(Path::new(env!("CARGO_MANIFEST_DIR")), input);
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| {
            let path = entry.unwrap().path();
            (path.file_name().unwrap().to_string_lossy().to_string(), std::fs::read(&path).unwrap())
        })
        .collect();
    files.sort();
    assert!(!files.is_empty(), "{}: empty corpus", dir.display());
    files
}

/// Feeds one input, turning a panic into a test failure that names the target and the input.
fn feed_without_panic(input: Input, label: &str, data: &[u8]) -> anyhow::Result<()> {
    match catch_unwind(AssertUnwindSafe(|| feed(input, data))) {
        Ok(result) => result,
        Err(_) => panic!("{}: {label} ({} bytes) panicked", input.name(), data.len()),
    }
}

#[test]
fn every_seed_of_every_target_loads() {
    for input in Input::ALL {
        for (name, data) in corpus(input) {
            // The seeds are valid inputs; a seed that fails to load would fuzz only the error path.
            if let Err(e) = feed_without_panic(input, &name, &data) {
                panic!("{}: seed {name} was refused: {e:#}", input.name());
            }
        }
    }
}

/// Inputs on which a fuzzing run crashed the renderer: each must now give an error or load, never
/// panic. (This test runs with overflow checks, as the fuzzer's builds do.)
#[test]
fn crashes_found_by_fuzzing_stay_fixed() {
    let mut replayed = 0;
    for input in Input::ALL {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions").join(input.name());
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for entry in entries {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            let data = std::fs::read(&path).unwrap();
            let _ = feed_without_panic(input, &name, &data);
            // Meshes also on the pure-Rust BVH, in this build with debug assertions.
            if matches!(input, Input::Obj | Input::Ply) {
                let bvh = catch_unwind(AssertUnwindSafe(|| feed_with(input, &data, AccelKind::Bvh)));
                assert!(bvh.is_ok(), "{}: {name} panicked on the BVH backend", input.name());
            }
            replayed += 1;
        }
    }
    assert!(replayed > 0, "no regression inputs found under fuzz/regressions");
}

#[derive(Clone, Debug)]
enum Edit {
    Flip {
        at: usize,
        bit: u8,
    },
    Insert {
        at: usize,
        byte: u8,
    },
    Delete {
        at: usize,
        len: usize,
    },
    Truncate {
        at: usize,
    },
    /// Copies a run of the input over another place in it (repeats tags, numbers, headers).
    Splice {
        from: usize,
        to: usize,
        len: usize,
    },
}

fn apply(data: &mut Vec<u8>, edit: &Edit) {
    let n = data.len().max(1);
    match *edit {
        Edit::Flip { at, bit } => {
            if let Some(b) = data.get_mut(at % n) {
                *b ^= 1 << (bit % 8);
            }
        }
        Edit::Insert { at, byte } => data.insert((at % n).min(data.len()), byte),
        Edit::Delete { at, len } => {
            let start = (at % n).min(data.len());
            let end = (start + len).min(data.len());
            data.drain(start..end);
        }
        Edit::Truncate { at } => data.truncate(at % n),
        Edit::Splice { from, to, len } => {
            let from = from % n;
            let end = (from + len).min(data.len());
            let run: Vec<u8> = data.get(from..end).map(<[u8]>::to_vec).unwrap_or_default();
            let to = (to % n).min(data.len());
            data.splice(to..(to + run.len()).min(data.len()), run);
        }
    }
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(at, bit)| Edit::Flip { at, bit }),
        (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| Edit::Insert { at, byte }),
        (any::<usize>(), 1usize..64).prop_map(|(at, len)| Edit::Delete { at, len }),
        any::<usize>().prop_map(|at| Edit::Truncate { at }),
        (any::<usize>(), any::<usize>(), 1usize..256).prop_map(|(from, to, len)| Edit::Splice {
            from,
            to,
            len
        }),
    ]
}

fn mutated_inputs_never_panic(input: Input, seed: usize, edits: &[Edit]) {
    let seeds = corpus(input);
    let (name, data) = &seeds[seed % seeds.len()];
    let mut data = data.clone();
    for e in edits {
        apply(&mut data, e);
    }
    let _ = feed_without_panic(input, &format!("{name} after {edits:?}"), &data);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn mutated_scenes_never_panic(seed in any::<usize>(), edits in prop::collection::vec(edit(), 1..6)) {
        mutated_inputs_never_panic(Input::SceneXml, seed, &edits);
    }

    #[test]
    fn mutated_obj_meshes_never_panic(seed in any::<usize>(), edits in prop::collection::vec(edit(), 1..6)) {
        mutated_inputs_never_panic(Input::Obj, seed, &edits);
    }

    #[test]
    fn mutated_ply_meshes_never_panic(seed in any::<usize>(), edits in prop::collection::vec(edit(), 1..6)) {
        mutated_inputs_never_panic(Input::Ply, seed, &edits);
    }

    #[test]
    fn mutated_exr_images_never_panic(seed in any::<usize>(), edits in prop::collection::vec(edit(), 1..6)) {
        mutated_inputs_never_panic(Input::Exr, seed, &edits);
    }

    #[test]
    fn mutated_png_images_never_panic(seed in any::<usize>(), edits in prop::collection::vec(edit(), 1..6)) {
        mutated_inputs_never_panic(Input::Png, seed, &edits);
    }
}

/// The fuzz harness is its own workspace with its own Cargo.lock, which `.ci/run` builds with
/// `--locked`: a dependency added to the renderer must be added to that lock too (run
/// `cargo metadata --format-version 1 --manifest-path fuzz/Cargo.toml` once), or CI's fuzz step
/// cannot build. This catches it in `cargo test`, without building the harness.
#[test]
fn the_fuzz_lock_file_has_every_dependency_of_the_renderer() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let lock = std::fs::read_to_string(root.join("fuzz/Cargo.lock")).unwrap();
    let section = manifest.split("\n[dependencies]\n").nth(1).unwrap().split("\n[").next().unwrap();
    let names: Vec<&str> = section
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .filter_map(|l| l.split_once('=').map(|(name, _)| name.trim()))
        .filter(|name| !name.is_empty())
        .collect();
    assert!(names.len() > 10, "parsed only {names:?} from [dependencies]");
    let missing: Vec<&&str> =
        names.iter().filter(|name| !lock.contains(&format!("name = \"{name}\"\n"))).collect();
    assert!(missing.is_empty(), "fuzz/Cargo.lock lacks {missing:?}: update it (see this test's comment)");
}
