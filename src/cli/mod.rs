//! Command-line interface: `render`, `info` and `bench`. Parsing is clap's; this module turns the
//! arguments into load and render options and writes the outputs with their metadata.

pub mod assets;
pub mod error;
pub mod plot_halfvector;
pub mod report;

use crate::accel::AccelKind;
use crate::image::{ImageBuf, Metadata};
use crate::integrators::{self, DepthLimits, IntegratorKind};
use crate::metropolis::direct::DirectPass;
use crate::metropolis::mutations::halfvector::TraceDirection;
use crate::metropolis::MutationKind;
use crate::path::MisHeuristic;
use crate::render::{self, RenderOptions, RenderStats};
use crate::scene::{LoadOptions, Scene};
use anyhow::{anyhow, bail, Context};
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

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
    Render(RenderArgs),
    /// Describe a scene: geometry, materials, lights, textures and which renderer features it needs.
    Info(SceneArgs),
    /// Benchmarks: `bench pt SCENE` (path tracer) or `bench rays SCENE` (Embree vs the Rust BVH).
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Run several integrators for the same wall time and report their error against a reference.
    Compare(report::CompareArgs),
    /// Render a long, checkpointed reference image (EXR) that --resume continues.
    Reference(report::ReferenceArgs),
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

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Path-tracer throughput and the share of time spent in ray queries.
    Pt(BenchArgs),
    /// Ray-query backends compared on the scene's ray sets and on a generated 1M-triangle scene.
    Rays(BenchRaysArgs),
    /// Integrators side by side on one scene: samples/s, rays/s and rays per sample, one run each.
    Integrators(BenchIntegratorsArgs),
    /// HSLT mutations per second, with the Newton corrector's rays batched and cast one at a time.
    Hslt(BenchHsltArgs),
}

#[derive(Args, Debug)]
pub struct StabilityArgs {
    /// Run only these cases (numbers 1-15, comma-separated); all by default.
    #[arg(long, value_delimiter = ',')]
    pub case: Vec<usize>,
    /// The test suite's smaller sample counts instead of the table's.
    #[arg(long)]
    pub quick: bool,
}

#[derive(Args, Debug)]
pub struct BenchHsltArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Stationary paths to propose from (one HSLT proposal each per pass).
    #[arg(long, default_value_t = 20_000)]
    pub proposals: usize,
    /// Passes per mode, alternating; the median is reported.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// The end the walk traces from: camera, light or rule (see `render --hslt-direction`).
    #[arg(long, value_name = "DIR", default_value = "camera", value_parser = ["camera", "light", "rule"])]
    pub direction: String,
}

#[derive(Args, Debug)]
pub struct BenchIntegratorsArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Comma-separated integrators to measure.
    #[arg(long, default_value = "pt,bdpt")]
    pub integrators: String,
    /// Samples per pixel for each measured run.
    #[arg(long, default_value_t = 4)]
    pub spp: u32,
    /// Measure each integrator this many times, alternating, and report the median.
    #[arg(long, default_value_t = 3)]
    pub repeats: u32,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
}

#[derive(Args, Debug)]
pub struct BenchRaysArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Rays per ray set.
    #[arg(long, default_value_t = 1_000_000)]
    pub rays: usize,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Triangles of the generated scene (0 = skip it).
    #[arg(long, default_value_t = 1_000_000)]
    pub large: usize,
}

#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene file (Mitsuba XML, version 3.x or 0.6).
    pub scene: PathBuf,
    /// Set a scene parameter declared with <default name=.. value=..>, e.g. -D spp=256.
    #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = parse_define)]
    pub define: Vec<(String, String)>,
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output image(s); the format follows the extension (.exr, .png, .jpg, .tif, .hdr). Repeatable.
    #[arg(short, long = "output", required = true)]
    pub output: Vec<PathBuf>,
    /// Integrator (overrides the scene's <integrator>): pt, bdpt, pssmlt, mlt, memlt, hslt, hslt+mlt
    /// (the path-space ones as far as this build implements their mutations).
    #[arg(long)]
    pub integrator: Option<String>,
    /// BDPT: also write each strategy's weighted contribution, for path depths up to N, as extra EXR
    /// layers named d<depth>_s<s>_t<t> (Veach's and pbrt's per-strategy figures).
    #[arg(long, value_name = "N")]
    pub bdpt_strategies: Option<u32>,
    /// BDPT: multiple-importance heuristic.
    #[arg(long, default_value = "power", value_parser = ["power", "balance"])]
    pub mis: String,
    /// Metropolis: independent BDPT samples in the seeding pass that estimates the normalisation and
    /// starts the chains (default: PSSMLT 4 per pixel, path-space methods 16 per pixel; at least 16384
    /// and 65536, at most 1048576).
    #[arg(long, value_name = "N")]
    pub seed_paths: Option<usize>,
    /// Metropolis: number of Markov chains, fixed so the image does not depend on the thread count
    /// (default: 64 for PSSMLT, 1024 for the path-space methods).
    #[arg(long, value_name = "N")]
    pub chains: Option<usize>,
    /// Path-space MLT (mlt, memlt, hslt, hslt+mlt): the mutation mixture with selection weights, e.g.
    /// bidir:1,lens:1,caustic:1,multichain:1 (known: bidir, lens, caustic, multichain, manifold, hslt,
    /// largestep, hvlens, hvcaustic).
    #[arg(long, value_name = "LIST")]
    pub mutations: Option<String>,
    /// MEMLT: manifold perturbation size λ (larger: smaller steps).
    #[arg(long, value_name = "L", default_value_t = 50.0)]
    pub lambda: f64,
    /// MEMLT, HSLT: glossy vertices with a roughness α below this are held at their half vector like
    /// specular ones by the manifold perturbation and the half-vector lens and caustic perturbations
    /// (0 treats every glossy vertex as diffuse).
    #[arg(long, value_name = "ALPHA", default_value_t = 0.1)]
    pub specular_threshold: f32,
    /// HSLT: the end the half-vector mutation's Newton walk traces from: camera, light, or rule (the
    /// end whose adjacent vertex is smoother).
    #[arg(long, value_name = "DIR", default_value = "camera", value_parser = ["camera", "light", "rule"])]
    pub hslt_direction: String,
    /// PSSMLT: probability of a large step (an independent new sample) per mutation.
    #[arg(long, value_name = "P", default_value_t = 0.3)]
    pub p_large: f64,
    /// Metropolis (pssmlt, mlt, memlt, hslt, hslt+mlt): samples per pixel of a separate pass for
    /// direct illumination (paths of one or two segments: the path tracer, and BDPT for emitters seen
    /// directly), so the chains render indirect light only, as Mitsuba's MLT family does; 0 leaves direct illumination to the chains [default: 16, or
    /// with --time the share --direct-share of it; no pass for path-space mixtures without a large step]
    #[arg(long, value_name = "N", conflicts_with = "direct_share")]
    pub direct_samples: Option<u32>,
    /// Metropolis: the fraction of --time the direct-illumination pass runs for [default: 0.1; no pass
    /// for path-space mixtures without a large step]
    #[arg(long, value_name = "F")]
    pub direct_share: Option<f64>,
    /// Samples per pixel (overrides the scene's sampler); with --time, a cap.
    #[arg(long)]
    pub spp: Option<u32>,
    /// Render for this many seconds.
    #[arg(long, value_name = "SECONDS")]
    pub time: Option<f64>,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Seed of all random streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Longest path in segments, Mitsuba's meaning (-1 = unbounded); overrides the scene.
    #[arg(long, allow_negative_numbers = true)]
    pub max_depth: Option<i32>,
    /// Shortest path in segments, counted as --max-depth counts them: 2 hides the emitters seen
    /// directly, 3 renders indirect light only (what the Metropolis chains render beside their direct
    /// pass, which then does not run, so an equal-time comparison at 3 measures the chains alone).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub min_depth: i32,
    /// Ray-query backend: embree (rounds as Mitsuba 3 does), embree-robust (Embree's watertight
    /// mode) or bvh (pure Rust, watertight).
    #[arg(long, default_value = "embree")]
    pub accel: String,
    /// No progress bar or summary.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Samples per pixel for each measured run.
    #[arg(long, default_value_t = 4)]
    pub spp: u32,
    /// Ray-query backend.
    #[arg(long, default_value = "embree")]
    pub accel: String,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
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

/// Set by the Ctrl-C handler; the render loop finishes its current tiles and returns.
static CANCEL: AtomicBool = AtomicBool::new(false);

pub fn run(cli: Cli) -> anyhow::Result<i32> {
    match cli.command {
        Command::Render(args) => run_render(args),
        Command::Info(args) => run_info(args),
        Command::Bench(BenchCommand::Pt(args)) => run_bench(args),
        Command::Bench(BenchCommand::Rays(args)) => run_bench_rays(args),
        Command::Bench(BenchCommand::Integrators(args)) => run_bench_integrators(args),
        Command::Bench(BenchCommand::Hslt(args)) => run_bench_hslt(args),
        Command::GenerateAssets(args) => assets::run(args),
        Command::Compare(args) => report::run_compare(args),
        Command::Reference(args) => report::run_reference(args),
        Command::Error(args) => error::run(args),
        Command::PlotHalfvector(args) => plot_halfvector::run(args),
        Command::Stability(args) => run_stability(args),
    }
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
        let ext = o.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("exr" | "png" | "jpg" | "jpeg" | "tif" | "tiff" | "hdr") => {}
            _ => bail!("{}: unsupported output format (use .exr, .png, .jpg, .tif or .hdr)", o.display()),
        }
        if let Some(dir) = o.parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.is_dir() {
                bail!("{}: the output directory {} does not exist", o.display(), dir.display());
            }
        }
    }
    Ok(())
}

fn run_render(args: RenderArgs) -> anyhow::Result<i32> {
    check_output_paths(&args.output)?;
    if let Some(t) = args.time {
        if !(t > 0.0 && t.is_finite()) {
            bail!("--time must be a positive number of seconds");
        }
    }
    if args.spp == Some(0) {
        bail!("--spp must be at least 1");
    }
    let scene = load(&args.scene, parse_accel(&args.accel)?)?;
    let kind_name = args.integrator.clone().unwrap_or_else(|| scene.integrator.kind.clone());
    let kind = IntegratorKind::parse(&kind_name).map_err(anyhow::Error::msg)?;
    let limits = DepthLimits {
        max_depth: args.max_depth.unwrap_or(scene.integrator.max_depth),
        rr_depth: scene.integrator.rr_depth,
    };
    if limits.max_depth == 0 || limits.max_depth < -1 {
        bail!("--max-depth must be -1 (unbounded) or at least 1");
    }
    if args.min_depth < 1 || (limits.max_depth > 0 && args.min_depth > limits.max_depth) {
        bail!("--min-depth must be at least 1 and at most the maximum depth ({})", limits.max_depth);
    }
    let mut settings = integrators::IntegratorSettings::new(limits, scene.integrator.hide_emitters);
    settings.min_depth = args.min_depth;
    settings.bdpt_strategies = args.bdpt_strategies;
    settings.mis = if args.mis == "balance" { MisHeuristic::Balance } else { MisHeuristic::Power };
    if args.bdpt_strategies.is_some() {
        if kind != IntegratorKind::Bdpt {
            bail!("--bdpt-strategies needs --integrator bdpt");
        }
        if args.output.iter().any(|o| o.extension().and_then(|e| e.to_str()) != Some("exr")) {
            bail!("--bdpt-strategies writes EXR layers: every output must end in .exr");
        }
    }
    if args.seed_paths == Some(0) || args.chains == Some(0) {
        bail!("--seed-paths and --chains must be at least 1");
    }
    if !(0.0..=1.0).contains(&args.p_large) {
        bail!("--p-large must be between 0 and 1");
    }
    settings.pssmlt.seed_paths = args.seed_paths;
    if let Some(chains) = args.chains {
        settings.pssmlt.chains = chains;
        settings.path_chains = Some(chains);
    }
    settings.pssmlt.p_large = args.p_large;
    if (args.direct_samples.is_some() || args.direct_share.is_some())
        && matches!(kind, IntegratorKind::Path | IntegratorKind::Bdpt)
    {
        bail!(
            "--direct-samples and --direct-share apply to the Metropolis integrators (pssmlt, mlt, memlt, \
             hslt, hslt+mlt)"
        );
    }
    if let Some(n) = args.direct_samples {
        settings.pssmlt.direct = if n == 0 { DirectPass::Off } else { DirectPass::Samples(n) };
    }
    if let Some(f) = args.direct_share {
        if !(0.0..1.0).contains(&f) {
            bail!("--direct-share must be at least 0 and below 1");
        }
        if args.time.is_none() {
            bail!("--direct-share needs --time (without a time limit, size the pass with --direct-samples)");
        }
        settings.pssmlt.direct = if f == 0.0 { DirectPass::Off } else { DirectPass::Share(f) };
    }
    if let Some(list) = &args.mutations {
        if !kind.is_path_space() {
            bail!("--mutations applies to the path-space integrators (mlt, memlt, hslt, hslt+mlt)");
        }
        let mixture = MutationKind::parse_mixture(list).map_err(|e| anyhow!("--mutations: {e}"))?;
        if let Some((m, _)) = mixture.iter().find(|(m, _)| !m.available()) {
            bail!("--mutations: mutation '{}' is not available in this build yet", m.name());
        }
        settings.mutations = Some(mixture);
    }
    if !(args.lambda.is_finite() && args.lambda > 0.0) {
        bail!("--lambda must be a positive number");
    }
    settings.mutation.lambda = args.lambda;
    if !(args.specular_threshold.is_finite() && args.specular_threshold >= 0.0) {
        bail!("--specular-threshold must be a roughness ≥ 0");
    }
    settings.mutation.specular_threshold = args.specular_threshold;
    settings.mutation.halfvector.direction = parse_hslt_direction(&args.hslt_direction)?;
    let integrator = integrators::make_with(kind, &settings);
    let options = RenderOptions {
        spp: args.spp.or(if args.time.is_some() { None } else { Some(scene.spp) }),
        time_limit: args.time.map(Duration::from_secs_f64),
        seed: args.seed,
        progress: !args.quiet,
        ..Default::default()
    };
    let _ = ctrlc::set_handler(|| {
        if CANCEL.swap(true, Ordering::SeqCst) {
            // A second Ctrl-C means the user does not want to wait for the current tiles.
            std::process::exit(130);
        }
        eprintln!("\ninterrupted: finishing the current tiles and writing the image so far");
    });
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let output = pool.install(|| integrator.render(&scene, &options, &CANCEL));
    let stats = output.stats;
    let image = output.film.to_image();
    let mut meta = metadata(&scene, kind.name(), &options, limits, threads, &stats);
    if args.min_depth > 1 {
        meta.push(("hslt.min_depth".into(), args.min_depth.to_string()));
    }
    meta.extend(output.metadata);
    let layers = output.film.layer_images();
    for out in &args.output {
        if layers.is_empty() {
            crate::image::write_image(out, &image, &meta)
        } else {
            let mut all: Vec<(&str, &ImageBuf)> = vec![("combined", &image)];
            all.extend(layers.iter().map(|(name, img)| (name.as_str(), img)));
            crate::image::write_exr_layers(out, &all, &meta).map(|_| ())
        }
        .with_context(|| format!("cannot write {}", out.display()))?;
    }
    if !args.quiet {
        print_summary(&args.output, &stats, threads);
        print_metropolis_summary(&meta);
    }
    Ok(if stats.interrupted { 130 } else { 0 })
}

fn metadata(
    scene: &Scene,
    integrator: &str,
    options: &RenderOptions,
    limits: DepthLimits,
    threads: usize,
    stats: &RenderStats,
) -> Metadata {
    vec![
        ("hslt.version".into(), env!("CARGO_PKG_VERSION").into()),
        ("hslt.scene".into(), scene.path.display().to_string()),
        ("hslt.integrator".into(), integrator.into()),
        ("hslt.seed".into(), options.seed.to_string()),
        ("hslt.spp".into(), stats.min_spp.to_string()),
        ("hslt.samples".into(), stats.samples.to_string()),
        ("hslt.max_depth".into(), limits.max_depth.to_string()),
        ("hslt.rr_depth".into(), limits.rr_depth.to_string()),
        ("hslt.threads".into(), threads.to_string()),
        ("hslt.elapsed_seconds".into(), format!("{:.3}", stats.elapsed.as_secs_f64())),
        ("hslt.invalid_samples".into(), stats.invalid_samples.to_string()),
        ("hslt.interrupted".into(), stats.interrupted.to_string()),
    ]
}

fn print_summary(outputs: &[PathBuf], stats: &RenderStats, threads: usize) {
    let secs = stats.elapsed.as_secs_f64().max(1e-9);
    eprintln!(
        "{} spp in {:.2} s on {} threads: {:.3} M samples/s, {:.2} M rays/s{}{}",
        stats.min_spp,
        secs,
        threads,
        stats.samples as f64 / secs * 1e-6,
        stats.rays as f64 / secs * 1e-6,
        if stats.invalid_samples > 0 {
            format!(", {} NaN/Inf samples dropped", stats.invalid_samples)
        } else {
            String::new()
        },
        if stats.interrupted { " (interrupted)" } else { "" },
    );
    for o in outputs {
        eprintln!("wrote {}", o.display());
    }
}

/// Metropolis statistics (acceptance per mutation) and warnings such as an all-black seeding pass.
fn print_metropolis_summary(meta: &Metadata) {
    let get = |key: &str| meta.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str());
    if let Some(status) = get("hslt.mlt.status") {
        eprintln!("warning: {status}");
    }
    if let (Some(m), Some(a)) = (get("hslt.mlt.mutations"), get("hslt.mlt.acceptance")) {
        eprintln!("{m} mutations, acceptance {a}");
        for (k, v) in meta {
            let Some(name) = k.strip_prefix("hslt.mlt.").and_then(|r| r.strip_suffix(".acceptance")) else {
                continue;
            };
            let field = |what: &str| get(&format!("hslt.mlt.{name}.{what}")).unwrap_or("0").to_string();
            let mut line = format!(
                "  {name}: {} proposed, acceptance {v}, {} zero-contribution, {} not applicable",
                field("proposed"),
                field("rejected_zero"),
                field("not_applicable")
            );
            let prefix = format!("hslt.mlt.{name}.");
            let detail = |part: &str| -> Vec<String> {
                meta.iter()
                    .filter_map(|(key, value)| {
                        let rest = key.strip_prefix(&prefix)?.strip_prefix(part)?;
                        Some(format!("{rest} {value}"))
                    })
                    .collect()
            };
            let failed = detail("failed.");
            if !failed.is_empty() {
                line += &format!("; failed: {}", failed.join(", "));
            }
            let means = detail("mean.");
            if !means.is_empty() {
                line += &format!("; mean {}", means.join(", "));
            }
            eprintln!("{line}");
        }
    }
}

fn run_info(args: SceneArgs) -> anyhow::Result<i32> {
    let scene = load(&args, AccelKind::Embree)?;
    print!("{}", describe(&scene));
    Ok(0)
}

/// The `hslt info` report.
pub fn describe(scene: &Scene) -> String {
    use std::fmt::Write;
    let f = &scene.features;
    let mut s = String::new();
    let _ = writeln!(s, "scene      {}", scene.path.display());
    let _ = writeln!(s, "film       {} x {}, {:?}", scene.film.width, scene.film.height, scene.film.rfilter);
    let _ = writeln!(s, "samples    {} per pixel", scene.spp);
    let _ = writeln!(
        s,
        "integrator {} (max_depth {}, rr_depth {})",
        scene.integrator.kind, scene.integrator.max_depth, scene.integrator.rr_depth
    );
    let _ = writeln!(s, "shapes     {}", scene.shapes.len());
    let _ = writeln!(s, "triangles  {}", f.triangles);
    let _ = writeln!(s, "materials  {}", f.bsdf_types.join(", "));
    let _ = writeln!(s, "lights     {} ({})", scene.lights.len(), f.light_types.join(", "));
    let _ = writeln!(s, "textures   {} bitmap(s)", f.textures);
    let _ = writeln!(s, "bounds     {:?} .. {:?}", scene.bounds.min, scene.bounds.max);
    let yes = |b: bool| if b { "yes" } else { "no" };
    let _ = writeln!(s, "needs      texture system: {}", yes(f.textures > 0));
    let _ =
        writeln!(s, "           manifold walk (specular/glossy vertices): {}", yes(f.needs_manifold_walk()));
    let _ = writeln!(s, "           refraction: {}", yes(f.has_transmission));
    let _ = writeln!(s, "           environment lighting: {}", yes(!scene.infinite_lights.is_empty()));
    s
}

fn run_bench(args: BenchArgs) -> anyhow::Result<i32> {
    let mut scene = load(&args.scene, parse_accel(&args.accel)?)?;
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let integrator = integrators::make(
        IntegratorKind::Path,
        DepthLimits { max_depth: scene.integrator.max_depth, rr_depth: scene.integrator.rr_depth },
        scene.integrator.hide_emitters,
    );
    let options = RenderOptions { spp: Some(args.spp), seed: 1, ..Default::default() };
    let never = AtomicBool::new(false);
    // Warm-up pass so page faults and lazy initialisation are not measured.
    pool.install(|| integrator.render(&scene, &RenderOptions { spp: Some(1), ..options.clone() }, &never));
    let plain = pool.install(|| integrator.render(&scene, &options, &never)).stats;
    let clock = Arc::new(crate::accel::timed::QueryClock::default());
    scene.replace_accel(|inner| Box::new(crate::accel::timed::TimedQuery::new(inner, clock.clone())));
    let inst = pool.install(|| integrator.render(&scene, &options, &never)).stats;
    let query_secs = clock.corrected_seconds();
    let busy = inst.elapsed.as_secs_f64() * threads as f64;
    let secs = plain.elapsed.as_secs_f64().max(1e-9);
    println!("scene            {}", scene.path.display());
    println!("threads          {threads}");
    println!("image            {} x {} at {} spp", scene.film.width, scene.film.height, args.spp);
    println!("samples/s        {:.0}", plain.samples as f64 / secs);
    println!("rays/s           {:.0}", plain.rays as f64 / secs);
    println!("rays per sample  {:.2}", plain.rays as f64 / plain.samples.max(1) as f64);
    println!(
        "time in {:<8} {:.1}% of worker time (instrumented run, {} calls, clock cost subtracted)",
        scene.accel().name(),
        100.0 * query_secs / busy.max(1e-9),
        clock.calls()
    );
    Ok(0)
}

fn run_bench_integrators(args: BenchIntegratorsArgs) -> anyhow::Result<i32> {
    let scene = load(&args.scene, AccelKind::Embree)?;
    let pool = thread_pool(args.threads)?;
    let limits = DepthLimits { max_depth: scene.integrator.max_depth, rr_depth: scene.integrator.rr_depth };
    let kinds = args
        .integrators
        .split(',')
        .map(|n| IntegratorKind::parse(n.trim()).map_err(anyhow::Error::msg))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let never = AtomicBool::new(false);
    let options = RenderOptions { spp: Some(args.spp.max(1)), seed: 1, ..Default::default() };
    let integrators: Vec<_> =
        kinds.iter().map(|&k| integrators::make(k, limits, scene.integrator.hide_emitters)).collect();
    // Warm up once each, then alternate the measured runs so load changes hit all integrators alike.
    for integrator in &integrators {
        pool.install(|| {
            integrator.render(&scene, &RenderOptions { spp: Some(1), ..options.clone() }, &never)
        });
    }
    let mut runs: Vec<Vec<RenderStats>> = vec![Vec::new(); kinds.len()];
    for _ in 0..args.repeats.max(1) {
        for (i, integrator) in integrators.iter().enumerate() {
            runs[i].push(pool.install(|| integrator.render(&scene, &options, &never)).stats);
        }
    }
    println!("scene      {}", scene.path.display());
    println!("threads    {}", pool.current_num_threads());
    println!(
        "image      {} x {} at {} spp, median of {} alternating runs",
        scene.film.width,
        scene.film.height,
        args.spp,
        args.repeats.max(1)
    );
    println!(
        "{:<10} {:>14} {:>12} {:>14} {:>16}",
        "integrator", "samples/s", "rays/s", "rays/sample", "time vs first"
    );
    let mut first = None;
    for (kind, stats) in kinds.iter().zip(&mut runs) {
        stats.sort_by_key(|s| s.elapsed);
        let median = &stats[stats.len() / 2];
        let secs = median.elapsed.as_secs_f64().max(1e-9);
        let base = *first.get_or_insert(secs);
        println!(
            "{:<10} {:>14.0} {:>12.0} {:>14.2} {:>15.2}x",
            kind.name(),
            median.samples as f64 / secs,
            median.rays as f64 / secs,
            median.rays as f64 / median.samples.max(1) as f64,
            secs / base
        );
    }
    Ok(0)
}

fn run_stability(args: StabilityArgs) -> anyhow::Result<i32> {
    use crate::stability::{self, Effort};
    let known: Vec<usize> = stability::cases().iter().map(|c| c.number).collect();
    if let Some(bad) = args.case.iter().find(|n| !known.contains(n)) {
        bail!("--case {bad}: no such stability case (known: {known:?})");
    }
    let effort = if args.quick { Effort::Quick } else { Effort::Full };
    let runs = stability::run(effort, &args.case);
    print!("{}", stability::table(&runs));
    Ok(if runs.iter().all(|r| r.report.passed()) { 0 } else { 1 })
}

fn run_bench_hslt(args: BenchHsltArgs) -> anyhow::Result<i32> {
    let scene = load(&args.scene, AccelKind::Embree)?;
    let direction = parse_hslt_direction(&args.direction)?;
    print!("{}", crate::bench::bench_hslt(&scene, args.proposals, args.repeats, direction)?);
    Ok(0)
}

fn run_bench_rays(args: BenchRaysArgs) -> anyhow::Result<i32> {
    let pool = thread_pool(args.threads)?;
    let scene = crate::bench::load_scene(&args.scene.scene, &args.scene.define)?;
    print!("{}", crate::bench::bench_rays(&scene, args.rays, &pool)?);
    if args.large > 0 {
        let n = ((args.large as f64 / 2.0).sqrt().ceil() as usize).max(2);
        println!();
        print!("{}", crate::bench::bench_rays(&crate::bench::large_scene(n), args.rays, &pool)?);
    }
    Ok(0)
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
) -> (render::Film, RenderStats) {
    let integrator = integrators::make(
        kind,
        DepthLimits { max_depth: scene.integrator.max_depth, rr_depth: scene.integrator.rr_depth },
        scene.integrator.hide_emitters,
    );
    let options = RenderOptions { spp: Some(spp), seed, ..Default::default() };
    let never = AtomicBool::new(false);
    let output = integrator.render(scene, &options, &never);
    (output.film, output.stats)
}
