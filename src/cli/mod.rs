//! Command-line interface, one file per subcommand (as in cargo's own source): `render`, `info`,
//! `bench`, `stability`, `compare`/`reference` (report), `error`, `plot-halfvector`. Parsing is clap's;
//! this module holds the command enum, what the subcommands share (scene loading, thread pool, output
//! checks, Ctrl-C) and the in-process render helpers the tests use.

pub mod assets;
mod bench;
mod compare;
pub mod error;
mod farm;
mod info;
pub mod plot_halfvector;
mod reference;
mod render;
mod stability;
pub mod stats_json;
mod summary;
mod tev;

pub use bench::{BenchArgs, BenchCommand, BenchHsltArgs, BenchIntegratorsArgs, BenchRaysArgs};
pub use compare::CompareArgs;
pub use info::describe;
pub use reference::{ReferenceArgs, REFERENCE_DEFAULT_SEED};
pub use render::RenderArgs;
pub use stability::StabilityArgs;

use crate::accel::AccelKind;
use crate::image::{read_image, ImageBuf, Metadata};
use crate::metropolis::mutations::halfvector::TraceDirection;
use crate::registry::{self, IntegratorKind};
use crate::render::{DepthLimits, RenderOptions, RenderStats};
use crate::scene::{LoadOptions, Scene};
use anyhow::{anyhow, bail, Context};
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Parser, Debug)]
#[command(
    name = "hslt",
    version,
    about = "Half-vector Space Light Transport renderer",
    propagate_version = true
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a Mitsuba XML scene to one or more images.
    Render(Box<RenderArgs>),
    /// Describe a scene: geometry, materials, lights, textures and which renderer features it needs.
    Info(SceneArgs),
    /// Benchmarks: `bench pt SCENE` (path tracer) or `bench rays SCENE` (Embree vs the Rust BVH).
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Run several integrators for the same wall time and report their error against a reference.
    Compare(compare::CompareArgs),
    /// Render a long, checkpointed reference image (EXR) that --resume continues.
    Reference(reference::ReferenceArgs),
    /// Merge parts of one render (`hslt render --part K/N`) into one image: exactly the single render
    /// for pixel integrators when all parts are there, and an unbiased image from any subset of them.
    Merge(farm::MergeArgs),
    /// Error of finished images against a reference (one image, or the mean of two independent
    /// renders): relative MSE per pixel and on block means, the worst 1% of pixels' share of it, RMSE,
    /// MAE, with each image's integrator, seed and samples from its metadata, as a Markdown table.
    Error(error::ErrorArgs),
    /// The HSLT supplement's half-vector plots (Fig. 4) for a path through one pixel.
    ///
    /// Sweeps vertex I's projected half vector h⊥ over the unit disk (all other half vectors and both
    /// endpoints fixed) and writes one PNG with three polar plots, left to right: the measurement
    /// contribution in half-vector measure f_H = f_A/|det J|; the local BSDF at vertex I in the same
    /// measure (f_s |n·ωo| |dωo/dωH| / |n·H|); and their |difference|, each normalised to a maximum of 1
    /// (viridis colours: dark blue 0, yellow 1). Black: the walk failed or a segment is occluded;
    /// transparent: outside the disk. +x is the shading tangent s, +y (up) is t.
    PlotHalfvector(plot_halfvector::PlotHalfvectorArgs),
    /// The fifteen stiff and extreme cases of the HSLT method (near-specular, grazing, long chains,
    /// singular J, ...): measures each and prints a Markdown table (case, measured, outcome).
    ///
    /// Exits with status 1 if any case fails. docs/stability.md is this command's output.
    Stability(StabilityArgs),
    /// Write the man pages and shell completions into a directory (used by scripts/build-deb.sh).
    #[command(hide = true)]
    GenerateAssets(assets::GenerateAssetsArgs),
}

#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene file (Mitsuba XML, version 3.x or 0.6).
    pub scene: PathBuf,
    /// Set a scene parameter declared with <default name=.. value=..>, e.g. -D spp=256.
    #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = parse_define)]
    pub define: Vec<(String, String)>,
}

fn parse_define(s: &str) -> Result<(String, String), String> {
    match s.split_once('=') {
        Some((k, v)) if !k.trim().is_empty() => Ok((k.trim().to_string(), v.to_string())),
        _ => Err(format!("'{s}' is not of the form NAME=VALUE")),
    }
}

pub(crate) fn parse_hslt_direction(name: &str) -> anyhow::Result<TraceDirection> {
    TraceDirection::parse(name).map_err(|e| anyhow!("--hslt-direction: {e}"))
}

fn parse_accel(name: &str) -> anyhow::Result<AccelKind> {
    match name {
        "embree" => Ok(AccelKind::Embree),
        "embree-robust" => Ok(AccelKind::EmbreeRobust),
        "bvh" => Ok(AccelKind::Bvh),
        other => bail!("unknown ray-query backend '{other}' (available: embree, embree-robust, bvh)"),
    }
}

/// Set by the Ctrl-C handler (and SIGTERM, SIGHUP); the render loop finishes its current work and returns.
static CANCEL: AtomicBool = AtomicBool::new(false);

/// A first Ctrl-C, SIGTERM or SIGHUP sets `CANCEL` (the command finishes its work in progress and
/// writes what exists, as `message` tells the user; a farm's scheduler sends SIGTERM at its time
/// limit); a second one means the user does not want to wait, and exits.
fn install_ctrlc_handler(message: &'static str) {
    let _ = ctrlc::set_handler(move || {
        if CANCEL.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("\ninterrupted: {message}");
    });
}

/// `--max-memory SIZE`, shared by the commands that render for long.
#[derive(Args, Debug, Clone, Default)]
pub struct MemoryArgs {
    /// Cap on resident memory, e.g. 4G or 512M: inputs that would not fit under it are refused while
    /// the scene loads, and a render that grows past it stops, writes the image so far and exits
    /// with status 1 (instead of the kernel's out-of-memory kill losing everything).
    #[arg(long, value_name = "SIZE", value_parser = crate::resources::parse_size)]
    pub max_memory: Option<u64>,
}

/// How often the memory watch reads the resident size: a render's memory grows by allocations of
/// tiles, layers and chains, so a tenth of a second is early enough and costs nothing measurable.
const MEMORY_POLL: std::time::Duration = std::time::Duration::from_millis(100);

impl MemoryArgs {
    /// Sets the cap for the loaders; call before loading the scene.
    fn apply(&self) {
        if let Some(cap) = self.max_memory {
            crate::resources::set_memory_cap(cap);
        }
    }

    /// Runs `work` while a thread polls the resident memory; past the cap it sets `CANCEL`, so the
    /// render stops as a Ctrl-C stops it, and the overshoot (resident bytes, cap) is returned.
    fn watch<T>(&self, work: impl FnOnce() -> T) -> (T, Option<(u64, u64)>) {
        if self.max_memory.is_none() {
            return (work(), None);
        }
        let done = AtomicBool::new(false);
        std::thread::scope(|scope| {
            let watcher = scope.spawn(|| {
                while !done.load(Ordering::Relaxed) {
                    if let Some(over) = crate::resources::resident_over_cap() {
                        CANCEL.store(true, Ordering::SeqCst);
                        return Some(over);
                    }
                    std::thread::park_timeout(MEMORY_POLL);
                }
                None
            });
            let result = work();
            done.store(true, Ordering::Relaxed);
            watcher.thread().unpark();
            // The watcher only reads /proc and sets flags; it cannot panic short of a bug in std.
            let over = watcher.join().unwrap_or(None);
            (result, over)
        })
    }

    /// The error a render that outgrew the cap ends with, after its outputs are written.
    fn exceeded(over: (u64, u64), outputs: &str) -> anyhow::Error {
        let (rss, cap) = over;
        anyhow!(
            "the render's resident memory reached {}, over --max-memory {}: it stopped early and {outputs} \
             holds the image so far",
            crate::resources::human_size(rss),
            crate::resources::human_size(cap)
        )
    }
}

pub fn run(cli: Cli) -> anyhow::Result<i32> {
    match cli.command {
        Command::Render(args) => render::run_render(*args),
        Command::Info(args) => info::run_info(args),
        Command::Bench(BenchCommand::Pt(args)) => bench::run_bench(args),
        Command::Bench(BenchCommand::Rays(args)) => bench::run_bench_rays(args),
        Command::Bench(BenchCommand::Integrators(args)) => bench::run_bench_integrators(args),
        Command::Bench(BenchCommand::Hslt(args)) => bench::run_bench_hslt(args),
        Command::GenerateAssets(args) => assets::run(args),
        Command::Compare(args) => compare::run_compare(args),
        Command::Reference(args) => reference::run_reference(args),
        Command::Merge(args) => farm::run_merge(args),
        Command::Error(args) => error::run(args),
        Command::PlotHalfvector(args) => plot_halfvector::run(args),
        Command::Stability(args) => stability::run_stability(args),
    }
}

fn check_seconds(flag: &str, v: f64) -> anyhow::Result<()> {
    if !(v > 0.0 && v.is_finite()) {
        bail!("{flag} must be a positive number, not {v}");
    }
    Ok(())
}

/// Reads an image to compare against and checks it matches the scene's film.
fn load_reference(path: &Path, scene: &Scene) -> anyhow::Result<ImageBuf> {
    let img =
        read_image(path, true).with_context(|| format!("cannot read the reference {}", path.display()))?;
    let (w, h) = (scene.film.width, scene.film.height);
    if (img.width, img.height) != (w, h) {
        bail!(
            "{}: the reference is {}x{} but the scene's film is {}x{} (render the reference with the same -D \
             options as the comparison)",
            path.display(),
            img.width,
            img.height,
            w,
            h
        );
    }
    Ok(img)
}

fn lookup<'a>(meta: &'a Metadata, key: &str) -> Option<&'a str> {
    meta.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

fn thread_pool(threads: usize) -> anyhow::Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("hslt-worker-{i}"))
        // Embree asks for flush-to-zero/denormals-are-zero in every thread that traces rays.
        .start_handler(|_| crate::accel::set_flush_denormals())
        .build()
        .context("cannot start the worker threads")
}

fn load(args: &SceneArgs, accel: AccelKind) -> anyhow::Result<Scene> {
    let scene = Scene::load(&args.scene, &LoadOptions { defines: args.define.clone(), accel })?;
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    Ok(scene)
}

fn check_output_paths(outputs: &[PathBuf]) -> anyhow::Result<()> {
    for o in outputs {
        crate::image::check_output_format(o)?;
        if let Some(dir) = o.parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.is_dir() {
                bail!("{}: the output directory {} does not exist", o.display(), dir.display());
            }
        }
    }
    Ok(())
}

/// Used by tests: loads a scene with overrides.
pub fn load_scene(path: &Path, defines: &[(&str, &str)]) -> anyhow::Result<Scene> {
    let defines = defines.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    Scene::load(path, &LoadOptions { defines, accel: AccelKind::Embree })
}

/// Renders a loaded scene in-process with a given integrator (tests and the comparison tooling).
pub fn render_scene(scene: &Scene, kind: IntegratorKind, spp: u32, seed: u64) -> (ImageBuf, RenderStats) {
    let (film, stats) = render_scene_film(scene, kind, spp, seed);
    (film.to_image(), stats)
}

/// As `render_scene`, returning the film (for per-pixel variances).
pub fn render_scene_film(
    scene: &Scene,
    kind: IntegratorKind,
    spp: u32,
    seed: u64,
) -> (crate::render::Film, RenderStats) {
    let integrator = registry::make(kind, DepthLimits::of_scene(scene), scene.integrator.hide_emitters);
    let options = RenderOptions { spp: Some(spp), seed, ..Default::default() };
    let never = AtomicBool::new(false);
    let output = integrator.render(scene, &options, &never);
    (output.film, output.stats)
}
