//! `hslt render`: loads a scene, builds the chosen integrator from the command line's settings, renders
//! with progress, time budget and Ctrl-C, and writes every output atomically with the seed, integrator
//! and sample count in its metadata.

use super::farm::{self, Checkpoint};
use super::tev::{TevStream, TEV_DEFAULT_ADDRESS, TEV_INTERVAL};
use super::{
    check_output_paths, check_seconds, install_ctrlc_handler, load, parse_accel, parse_hslt_direction,
    thread_pool, MemoryArgs, SceneArgs, CANCEL,
};
use crate::image::{ImageBuf, Metadata};
use crate::integrators::aov::{Aov, AovPass};
use crate::metropolis::direct::DirectPass;
use crate::metropolis::MutationKind;
use crate::path::MisHeuristic;
use crate::registry::{self, IntegratorKind};
use crate::render::{DepthLimits, RenderOptions, RenderState, RenderStats, Work};
use crate::render::{Snapshot, SnapshotHook};
use crate::scene::Scene;
use anyhow::{anyhow, bail, Context};
use clap::Args;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file (Mitsuba XML, version 3.x or 0.6); with --resume, the checkpoint's.
    #[arg(value_name = "SCENE", required_unless_present = "resume", conflicts_with = "resume")]
    pub scene: Option<PathBuf>,
    /// Set a scene parameter declared with <default name=.. value=..>, e.g. -D spp=256.
    #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = super::parse_define, conflicts_with = "resume")]
    pub define: Vec<(String, String)>,
    /// Output image(s); the format follows the extension (.exr, .png, .jpg, .tif, .hdr). Repeatable.
    #[arg(short, long = "output", required = true)]
    pub output: Vec<PathBuf>,
    /// Integrator (overrides the scene's <integrator>): pt, bdpt, pssmlt, mlt, memlt, hslt, hslt+mlt
    /// (the path-space ones as far as this build implements their mutations).
    #[arg(long, conflicts_with = "resume")]
    pub integrator: Option<String>,
    /// Render the K-th of N disjoint shares of the work, for a farm (1 ≤ K ≤ N): pixel integrators
    /// take their share of every pixel's sample indices (with --spp the N parts together are exactly
    /// the single render with the same seed; with only --time each part draws streams of its own),
    /// Metropolis ones their share of the seed samples, chains and mutations. EXR outputs keep what
    /// `hslt merge` needs to combine any subset of the parts.
    #[arg(long, value_name = "K/N", value_parser = super::farm::parse_part, conflicts_with = "resume")]
    pub part: Option<crate::render::Share>,
    /// Keep the render's state in this EXR (the image so far, the film's sums and the command line),
    /// written atomically every --checkpoint-every seconds, at the end, and when Ctrl-C, SIGTERM or
    /// SIGHUP stops the render; `hslt render --resume FILE -o OUT` continues it.
    #[arg(long, value_name = "FILE.exr")]
    pub checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints.
    #[arg(long, value_name = "SECONDS", default_value_t = 300.0)]
    pub checkpoint_every: f64,
    /// Continue the render recorded in this checkpoint: its scene (refused if the file changed),
    /// integrator, options, seed and remaining work (--spp, --time) come from it; give the outputs,
    /// and optionally --threads, --quiet, --checkpoint (default: this same file) and the like. A pixel
    /// integrator continues its per-pixel sample streams, so the result equals the uninterrupted
    /// render; a Metropolis one adds new chains (a fresh seeding pass) and pools b with the earlier runs.
    #[arg(long, value_name = "FILE.exr")]
    pub resume: Option<PathBuf>,
    /// BDPT: also write each strategy's weighted contribution, for path depths up to N, as extra EXR
    /// layers named d<depth>_s<s>_t<t> (Veach's and pbrt's per-strategy figures).
    #[arg(long, value_name = "N")]
    pub bdpt_strategies: Option<u32>,
    /// BDPT: multiple-importance heuristic.
    #[arg(long, default_value = "power", value_parser = ["power", "balance"])]
    pub mis: String,
    /// Metropolis: independent BDPT samples in the seeding pass that estimates the normalisation and
    /// starts the chains (default: PSSMLT 4 per pixel, at least 16384; path-space methods one per 16
    /// mutations, at least 16 per pixel and 65536, at most 2^24, and with --time as many as fit in a
    /// fifth of it).
    #[arg(long, value_name = "N")]
    pub seed_paths: Option<usize>,
    /// Path-space Metropolis (mlt, memlt, hslt, hslt+mlt) with --time: the fraction of it the seeding
    /// pass runs for; the chains keep the energy of every path family where the seeding pass put it, so
    /// a thin pass leaves blotches [default: 0.4]
    #[arg(long, value_name = "F", conflicts_with = "seed_paths")]
    pub seed_share: Option<f64>,
    /// Metropolis: number of Markov chains, fixed so the image does not depend on the thread count
    /// (default: 64 for PSSMLT, 4096 for the path-space methods).
    #[arg(long, value_name = "N")]
    pub chains: Option<usize>,
    /// Path-space MLT: mutations a chain runs between restarts from fresh draws of the seeding pass, so
    /// a chain caught on a rare bright path holds its energy there only that long; 0 never restarts
    /// [default: 1024].
    #[arg(long, value_name = "N")]
    pub restart_every: Option<u64>,
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
    /// HSLT: what the half-vector mutation moves: `sub`, a stretch of the path between two rough
    /// vertices (or its ends), chosen with short stretches preferred (improved HSLT, Hanika et al.
    /// 2015), or `whole`, every inner vertex with both ends held (the 2014 paper).
    #[arg(long, value_name = "WHICH", default_value = "whole", value_parser = ["whole", "sub"])]
    pub hslt_chains: String,
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
    #[arg(long, conflicts_with = "resume")]
    pub spp: Option<u32>,
    /// Render for this many seconds.
    #[arg(long, value_name = "SECONDS", conflicts_with = "resume")]
    pub time: Option<f64>,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Seed of all random streams.
    #[arg(long, default_value_t = 0, conflicts_with = "resume")]
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
    // A resumed render is the recorded command line with this one's outputs and run options.
    let resumed = args.resume.as_deref().map(Checkpoint::open).transpose()?;
    let (args, command_line) = match &resumed {
        Some(c) => (c.render_args(&args)?, c.args.clone()),
        None => (args, std::env::args().skip(1).collect::<Vec<String>>()),
    };
    check_output_paths(&args.output)?;
    let keeps_state = args.part.is_some() || args.checkpoint.is_some();
    if let Some(path) = &args.checkpoint {
        if path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() != Some("exr") {
            bail!("--checkpoint {}: a checkpoint is an .exr file", path.display());
        }
        check_output_paths(std::slice::from_ref(path))?;
        check_seconds("--checkpoint-every", args.checkpoint_every)?;
    }
    if keeps_state && args.bdpt_strategies.is_some() {
        bail!("--bdpt-strategies cannot be combined with --part, --checkpoint or --resume (its layers are not merged)");
    }
    if args.part.is_some() {
        if args.aov.is_some() {
            bail!("--aov cannot be combined with --part (render the AOVs once, apart from the parts)");
        }
        if !args.output.iter().any(|o| o.extension().and_then(|e| e.to_str()) == Some("exr")) {
            bail!("--part writes what `hslt merge` needs into EXR outputs: give at least one output ending in .exr");
        }
    }
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
    let scene_args =
        SceneArgs { scene: args.scene.clone().context("no scene file given")?, define: args.define.clone() };
    let scene = load(&scene_args, parse_accel(&args.accel)?)?;
    let scene_hash =
        if keeps_state { Some(farm::scene_hash(&scene_args.scene, &args.define)?) } else { None };
    let earlier = match &resumed {
        Some(c) => Some(c.state(scene_hash.as_deref().unwrap_or_default(), scene.film.rfilter)?),
        None => None,
    };
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
    if let Some(f) = args.seed_share {
        if !kind.is_path_space() {
            bail!("--seed-share applies to the path-space integrators (mlt, memlt, hslt, hslt+mlt)");
        }
        if !(0.0..1.0).contains(&f) {
            bail!("--seed-share must be at least 0 and below 1");
        }
        if args.time.is_none() {
            bail!("--seed-share needs --time (without a time limit, size the pass with --seed-paths)");
        }
        settings.seed_share = Some(f);
    }
    if let Some(chains) = args.chains {
        settings.pssmlt.chains = chains;
        settings.path_chains = Some(chains);
    }
    settings.restart_every = args.restart_every;
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
    settings.mutation.halfvector.sub_chains = args.hslt_chains == "sub";
    let options = RenderOptions {
        spp: args.spp.or(if args.time.is_some() { None } else { Some(scene.spp) }),
        time_limit: args.time.map(Duration::from_secs_f64),
        seed: args.seed,
        progress: !args.quiet,
        share: args.part.unwrap_or_default(),
        ..Default::default()
    };
    if let Some(share) = args.part {
        farm::check_part(kind, share, &options, &settings)?;
    }
    let integrator = registry::make_with(kind, &settings);
    // What this run renders: all of it, or the rest of a resumed render (`None`: nothing is left).
    let segment = match (&resumed, &earlier) {
        // A complete render resumed again only writes its outputs (a requeued farm task, say).
        (Some(c), Some(_)) if c.complete => None,
        (Some(c), Some(state)) => farm::continued_options(&options, state, c, &scene),
        _ => Some(options.clone()),
    };
    let mut run_options =
        segment.clone().unwrap_or_else(|| RenderOptions { spp: Some(0), ..options.clone() });
    let (elapsed_before, segments) = resumed.as_ref().map_or((0.0, 1), |c| (c.elapsed, c.segments + 1));
    let scene_path = std::fs::canonicalize(&scene_args.scene).unwrap_or_else(|_| scene_args.scene.clone());
    // What every state file of this render records besides its work: the part, the scene's hash and
    // the options the parts must share, and for a checkpoint the command line and time so far.
    let mut state_fields: Metadata = Vec::new();
    if let Some(hash) = &scene_hash {
        let share = args.part.unwrap_or_default();
        state_fields.push((farm::PART_COUNT.into(), share.count.to_string()));
        state_fields.push((farm::PART_COVERS.into(), (share.index + 1).to_string()));
        state_fields.push((farm::SCENE_HASH.into(), hash.clone()));
        state_fields.push((farm::SETTINGS.into(), farm::image_settings(&args)));
        if args.part.is_some() {
            state_fields.push(("hslt.part".into(), format!("{}/{}", share.index + 1, share.count)));
        }
    }
    let writer = args.checkpoint.clone().map(|path| {
        let base = metadata(&scene, kind.name(), &options, limits, 0, &RenderStats::default());
        Arc::new(farm::CheckpointWriter {
            path,
            earlier: earlier.clone(),
            meta: base.into_iter().chain(state_fields.iter().cloned()).collect(),
            command_line: command_line.clone(),
            scene: scene_path.clone(),
            elapsed_before,
            segments,
        })
    });
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
        let mut times: Vec<Duration> = Vec::new();
        let within = |t: &Duration| run_options.time_limit.is_none_or(|limit| *t < limit);
        let viewer = tev.take().filter(TevStream::is_connected).map(|mut stream| {
            let (send, receive) = std::sync::mpsc::sync_channel::<ImageBuf>(1);
            times.extend((1..=100_000u32).map(|k| TEV_INTERVAL * k).take_while(within));
            let handle = scope.spawn(move || {
                for image in receive {
                    stream.send(&image);
                }
                stream
            });
            (send, handle)
        });
        let every = Duration::from_secs_f64(args.checkpoint_every.min(1e9));
        if writer.is_some() {
            times.extend((1..=100_000u32).map(|k| every * k).take_while(within));
        }
        times.sort();
        times.dedup();
        let sender = viewer.as_ref().map(|(send, _)| send.clone());
        let checkpoints = writer.clone();
        let next_checkpoint = std::sync::Mutex::new(every);
        let sink = move |s: &Snapshot| {
            if let Some(send) = &sender {
                let _ = send.try_send(s.image.clone());
            }
            let (Some(w), Some(state)) = (&checkpoints, &s.state) else { return };
            let mut next = next_checkpoint.lock().unwrap_or_else(|e| e.into_inner());
            if s.elapsed >= *next {
                // The first multiple of the interval after now, however many passed since the last.
                *next = every.mul_f64((s.elapsed.as_secs_f64() / every.as_secs_f64()).floor() + 1.0);
                if let Err(e) = w.write(state, s.elapsed.as_secs_f64(), false, &Vec::new()) {
                    // The render goes on: the next checkpoint or the final write may still succeed.
                    eprintln!("warning: checkpoint not written: {e:#}");
                }
            }
        };
        if !times.is_empty() {
            run_options.snapshots =
                Some(SnapshotHook { times, sink: Arc::new(sink), with_state: writer.is_some() });
        }
        let result = args.memory.watch(|| match &segment {
            Some(_) => pool.install(|| integrator.render(&scene, &run_options, &CANCEL)),
            None => farm::nothing_left(&scene, earlier.as_ref()),
        });
        // Dropping the hook drops the last sender, which ends the viewer's loop.
        run_options.snapshots = None;
        tev = viewer.and_then(|(send, handle)| {
            drop(send);
            handle.join().ok()
        });
        result
    });
    let mut stats = output.stats;
    // The render's state: this run's film, and for a resumed render the earlier runs' with it.
    let mut state = RenderState::new(output.film, output.work);
    if let Some(e) = &earlier {
        let mut total = e.clone();
        total.absorb(&state).map_err(|err| anyhow!("cannot add this run to the checkpoint's: {err}"))?;
        state = total;
    }
    let pixels = (scene.film.width * scene.film.height).max(1) as u64;
    (stats.min_spp, stats.samples) = match state.work {
        Work::Pixels { spp } => (spp.min(u32::MAX as u64) as u32, spp * pixels),
        Work::Chains { mutations, .. } => ((mutations / pixels).min(u32::MAX as u64) as u32, mutations),
    };
    stats.elapsed += Duration::from_secs_f64(elapsed_before);
    let image = state.image();
    if let Some(stream) = tev.as_mut() {
        stream.send(&image);
    }
    let mut meta = metadata(&scene, kind.name(), &options, limits, threads, &stats);
    if args.min_depth > 1 {
        meta.push(("hslt.min_depth".into(), args.min_depth.to_string()));
    }
    meta.extend(output.metadata);
    meta.extend(process_metadata(&scene, &stats));
    if resumed.is_some() {
        meta.push(("hslt.resumed_segments".into(), segments.to_string()));
    }
    meta.extend(state_fields.iter().cloned());
    let layers = state.film.layer_images();
    let state_layers = if keeps_state { state.layers() } else { Vec::new() };
    let state_meta = match keeps_state {
        true => state.metadata().map_err(|e| anyhow!("cannot record the render's state: {e}"))?,
        false => Vec::new(),
    };
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
        if layers.is_empty() && (aovs.is_empty() && state_layers.is_empty() || !is_exr) {
            crate::image::write_image(out, &image, &meta)
        } else {
            let mut all: Vec<(&str, &ImageBuf, Option<&[&str]>)> = vec![("combined", &image, None)];
            all.extend(layers.iter().map(|(name, img)| (name.as_str(), img, None)));
            all.extend(aovs.iter().map(|(aov, img)| (aov.name(), img, Some(aov.channels()))));
            all.extend(state_layers.iter().map(|(name, img)| (*name, img, None)));
            let mut meta = meta.clone();
            meta.extend(state_meta.iter().cloned());
            crate::image::write_exr_parts(out, &all, &meta).map(|_| ())
        }
        .with_context(|| format!("cannot write {}", out.display()))?;
    }
    if let Some(w) = &writer {
        let complete = !stats.interrupted && over_memory.is_none();
        // The final state replaces the checkpoint whole: written from the total, not added to it.
        let earlier_free = farm::CheckpointWriter { earlier: None, elapsed_before: 0.0, ..(**w).clone() };
        earlier_free
            .write(&state, stats.elapsed.as_secs_f64(), complete, &meta)
            .with_context(|| format!("cannot write the checkpoint {}", w.path.display()))?;
        if !args.quiet {
            eprintln!(
                "checkpoint {}{}",
                w.path.display(),
                if complete { " (complete)" } else { ": continue with `hslt render --resume` it" }
            );
        }
    }
    if !args.quiet {
        if segment.is_none() {
            eprintln!("nothing left to render: the checkpoint holds all the work asked for");
        }
        super::summary::print_summary(&args.output, &stats, threads);
        super::summary::print_metropolis_summary(&meta);
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
