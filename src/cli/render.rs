//! `hslt render`: loads a scene, builds the chosen integrator from the command line's settings, renders
//! with progress, time budget and Ctrl-C, and writes every output atomically with the seed, integrator
//! and sample count in its metadata.

use super::tev::{TevStream, TEV_DEFAULT_ADDRESS, TEV_INTERVAL};
use super::{
    check_output_paths, install_ctrlc_handler, load, parse_accel, parse_hslt_direction, thread_pool,
    MemoryArgs, SceneArgs, CANCEL,
};
use crate::image::{ImageBuf, Metadata};
use crate::integrators::aov::{Aov, AovPass};
use crate::metropolis::direct::DirectPass;
use crate::metropolis::MutationKind;
use crate::path::MisHeuristic;
use crate::registry::{self, IntegratorKind};
use crate::render::{DepthLimits, RenderOptions, RenderStats};
use crate::render::{Snapshot, SnapshotHook};
use crate::scene::Scene;
use anyhow::{anyhow, bail, Context};
use clap::Args;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

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
    #[command(flatten)]
    pub memory: MemoryArgs,
    /// Also write the render's statistics as JSON (integrator, seed, resolution, samples, wall and
    /// CPU seconds, rays, samples/s, dropped NaN/Inf samples, peak memory, and for the Metropolis
    /// integrators each mutation's proposals, acceptance and failures): the `hslt.*` fields of the
    /// EXR header, nested at their dots.
    #[arg(long, value_name = "FILE")]
    pub stats_json: Option<PathBuf>,
    /// Auxiliary EXR layers for denoisers, any of albedo,normal,depth: layers `albedo` (R,G,B),
    /// `normal` (X,Y,Z, world space) and `depth` (Z) at the first non-specular surface, as Intel Open
    /// Image Denoise and Blender name them, from a pass of --aov-spp samples per pixel beside the render.
    /// PNG and other outputs stay beauty only.
    #[arg(long, value_name = "LIST")]
    pub aov: Option<String>,
    /// Show the image while it renders in a running tev (https://github.com/Tom94/tev), at
    /// HOST:PORT [default: 127.0.0.1:14158, tev's own]; refreshed every second, for every integrator
    /// (the Metropolis ones show their normalised estimate so far).
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = TEV_DEFAULT_ADDRESS)]
    pub tev: Option<String>,
    /// Samples per pixel of the --aov pass.
    #[arg(long, value_name = "N", default_value_t = 16)]
    pub aov_spp: u32,
}

pub(super) fn run_render(args: RenderArgs) -> anyhow::Result<i32> {
    check_output_paths(&args.output)?;
    if let Some(dir) = args.stats_json.as_ref().and_then(|p| p.parent()).filter(|d| !d.as_os_str().is_empty())
    {
        if !dir.is_dir() {
            bail!("--stats-json: the directory {} does not exist", dir.display());
        }
    }
    if let Some(t) = args.time {
        if !(t > 0.0 && t.is_finite()) {
            bail!("--time must be a positive number of seconds");
        }
    }
    if args.spp == Some(0) {
        bail!("--spp must be at least 1");
    }
    let aov_list = args.aov.as_deref().map(Aov::parse_list).transpose().map_err(|e| anyhow!("--aov: {e}"))?;
    if aov_list.is_some() {
        if args.aov_spp == 0 {
            bail!("--aov-spp must be at least 1");
        }
        if !args.output.iter().any(|o| o.extension().and_then(|e| e.to_str()) == Some("exr")) {
            bail!("--aov writes EXR layers: give at least one output ending in .exr");
        }
    }
    args.memory.apply();
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
    let mut settings = registry::IntegratorSettings::new(limits, scene.integrator.hide_emitters);
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
    let integrator = registry::make_with(kind, &settings);
    let mut options = RenderOptions {
        spp: args.spp.or(if args.time.is_some() { None } else { Some(scene.spp) }),
        time_limit: args.time.map(Duration::from_secs_f64),
        seed: args.seed,
        progress: !args.quiet,
        ..Default::default()
    };
    install_ctrlc_handler("finishing the current tiles and writing the image so far");
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let mut tev = args.tev.as_deref().map(|address| {
        let name = args.output[0].file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        TevStream::connect(address, &name, scene.film.width, scene.film.height)
    });
    let (output, over_memory) = std::thread::scope(|scope| {
        // The live view: snapshots every TEV_INTERVAL go through a channel of one to a thread that
        // sends them, so the render never waits on the network (a frame tev is still reading is
        // skipped instead).
        let viewer = tev.take().filter(TevStream::is_connected).map(|mut stream| {
            let (send, receive) = std::sync::mpsc::sync_channel::<ImageBuf>(1);
            let times = (1..=100_000u32)
                .map(|k| TEV_INTERVAL * k)
                .take_while(|t| options.time_limit.is_none_or(|limit| *t < limit))
                .collect();
            let sink = move |s: &Snapshot| {
                let _ = send.try_send(s.image.clone());
            };
            options.snapshots = Some(SnapshotHook { times, sink: Arc::new(sink) });
            scope.spawn(move || {
                for image in receive {
                    stream.send(&image);
                }
                stream
            })
        });
        let result = args.memory.watch(|| pool.install(|| integrator.render(&scene, &options, &CANCEL)));
        // Dropping the hook drops the sender, which ends the viewer's loop.
        options.snapshots = None;
        tev = viewer.and_then(|v| v.join().ok());
        result
    });
    let stats = output.stats;
    let image = output.film.to_image();
    if let Some(stream) = tev.as_mut() {
        stream.send(&image);
    }
    let mut meta = metadata(&scene, kind.name(), &options, limits, threads, &stats);
    if args.min_depth > 1 {
        meta.push(("hslt.min_depth".into(), args.min_depth.to_string()));
    }
    meta.extend(output.metadata);
    meta.extend(process_metadata(&scene, &stats));
    let layers = output.film.layer_images();
    let aovs = match &aov_list {
        Some(list) if !CANCEL.load(std::sync::atomic::Ordering::Relaxed) => {
            let aov_options =
                RenderOptions { spp: Some(args.aov_spp), seed: args.seed ^ AOV_SEED, ..Default::default() };
            let pass = AovPass { aovs: list.clone() };
            let (film, _) = pool.install(|| crate::render::render(&scene, &pass, &aov_options, &CANCEL));
            meta.push(("hslt.aov_spp".into(), args.aov_spp.to_string()));
            aov_layers(list, film.layer_images())
        }
        _ => Vec::new(),
    };
    for out in &args.output {
        let is_exr = out.extension().and_then(|e| e.to_str()) == Some("exr");
        if layers.is_empty() && (aovs.is_empty() || !is_exr) {
            crate::image::write_image(out, &image, &meta)
        } else {
            let mut all: Vec<(&str, &ImageBuf, Option<&[&str]>)> = vec![("combined", &image, None)];
            all.extend(layers.iter().map(|(name, img)| (name.as_str(), img, None)));
            all.extend(aovs.iter().map(|(aov, img)| (aov.name(), img, Some(aov.channels()))));
            crate::image::write_exr_parts(out, &all, &meta).map(|_| ())
        }
        .with_context(|| format!("cannot write {}", out.display()))?;
    }
    if !args.quiet {
        print_summary(&args.output, &stats, threads);
        print_metropolis_summary(&meta);
    }
    if let Some(path) = &args.stats_json {
        let text = serde_json::to_string_pretty(&super::stats_json::stats_document(&meta))? + "\n";
        crate::report::write_atomic(path, text.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(over) = over_memory {
        let names: Vec<String> = args.output.iter().map(|o| o.display().to_string()).collect();
        return Err(MemoryArgs::exceeded(over, &names.join(", ")));
    }
    Ok(if stats.interrupted { 130 } else { 0 })
}

pub(super) fn metadata(
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

/// Mixed into the seed of the --aov pass, so its samples are not the render's.
const AOV_SEED: u64 = 0xA0F5_EED0_0000_0001;

/// The AOV pass's film layers as images with each AOV's channel count (depth: one channel).
fn aov_layers(aovs: &[Aov], layers: Vec<(String, ImageBuf)>) -> Vec<(Aov, ImageBuf)> {
    aovs.iter()
        .zip(layers)
        .map(|(&aov, (_, img))| {
            let channels = aov.channels().len();
            if channels == img.channels {
                return (aov, img);
            }
            let mut out = ImageBuf::new(img.width, img.height, channels);
            for (dst, src) in out.data.chunks_mut(channels).zip(img.data.chunks(img.channels)) {
                dst.copy_from_slice(&src[..channels]);
            }
            (aov, out)
        })
        .collect()
}

/// What the process as a whole spent, for the metadata (and so --stats-json): the resolution, rays,
/// throughput, CPU time and peak memory.
fn process_metadata(scene: &Scene, stats: &RenderStats) -> Metadata {
    let secs = stats.elapsed.as_secs_f64().max(1e-9);
    let mut meta: Metadata = vec![
        ("hslt.width".into(), scene.film.width.to_string()),
        ("hslt.height".into(), scene.film.height.to_string()),
        ("hslt.rays".into(), stats.rays.to_string()),
        ("hslt.shadow_rays".into(), stats.shadow_rays.to_string()),
        ("hslt.closest_hit_rays".into(), stats.rays.saturating_sub(stats.shadow_rays).to_string()),
        ("hslt.samples_per_second".into(), format!("{:.1}", stats.samples as f64 / secs)),
    ];
    if let Some(cpu) = crate::resources::cpu_seconds() {
        meta.push(("hslt.cpu_seconds".into(), format!("{cpu:.3}")));
    }
    if let Some(peak) = crate::resources::peak_resident_bytes() {
        meta.push(("hslt.peak_memory_bytes".into(), peak.to_string()));
    }
    meta
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
        if let (Some(stuck), Some(chains), Some(longest), Some(share)) = (
            get("hslt.mlt.chains_stuck"),
            get("hslt.mlt.chains"),
            get("hslt.mlt.longest_rejection_streak"),
            get("hslt.mlt.stuck_share"),
        ) {
            eprintln!(
                "chains stuck ({} or more rejections in a row): {stuck} of {chains}; longest run {longest}; \
                 share of mutations in such runs {share}",
                crate::metropolis::chain::STUCK_STREAK
            );
        }
        for (k, v) in meta {
            let Some(name) = k.strip_prefix("hslt.mlt.").and_then(|r| r.strip_suffix(".acceptance")) else {
                continue;
            };
            let field = |what: &str| get(&format!("hslt.mlt.{name}.{what}")).unwrap_or("0").to_string();
            let cost = get(&format!("hslt.mlt.{name}.microseconds_per_proposal"))
                .map(|us| format!(", {us} µs each"))
                .unwrap_or_default();
            let mut line = format!(
                "  {name}: {} proposed, acceptance {v}{cost}, {} zero-contribution, {} not applicable",
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
