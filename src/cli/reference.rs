//! `hslt reference`: a long render written as a checkpointed EXR that `--resume` continues with the
//! same integrator and seed, combining the runs weighted by their work.

use super::render::metadata;
use super::{
    check_seconds, install_ctrlc_handler, load, load_reference, lookup, parse_accel, thread_pool, MemoryArgs,
    SceneArgs, CANCEL,
};
use crate::image::{read_exr_metadata, write_image, ImageBuf};
use crate::registry::{self, IntegratorKind};
use crate::render::{DepthLimits, RenderOptions, RenderStats, Snapshot, SnapshotHook};
use crate::scene::Scene;
use anyhow::{bail, Context};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Seed `reference` uses unless told otherwise: different from the other commands' default 0, so a
/// reference is never made of the very samples the compared renders take.
pub const REFERENCE_DEFAULT_SEED: u64 = 1_000_003;

#[derive(Args, Debug)]
pub struct ReferenceArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output EXR; rewritten at every checkpoint.
    #[arg(short, long = "output")]
    pub output: PathBuf,
    /// Integrator (default: the scene's; when resuming: the file's).
    #[arg(long)]
    pub integrator: Option<String>,
    /// Wall time of this run (a resumed run adds to the file's).
    #[arg(long, value_name = "SECONDS")]
    pub time: Option<f64>,
    /// Samples per pixel of this run (a resumed run adds to the file's); with --time, a cap.
    #[arg(long)]
    pub spp: Option<u32>,
    /// Continue the render stored in the output file, with its integrator and seed.
    #[arg(long)]
    pub resume: bool,
    /// Minutes between checkpoints.
    #[arg(long, default_value_t = 5.0, value_name = "MINUTES")]
    pub checkpoint_minutes: f64,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Seed of all random streams (default 1000003; when resuming: the file's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Ray-query backend.
    #[arg(long, default_value = "embree")]
    pub accel: String,
    /// No progress bar or summary.
    #[arg(short, long)]
    pub quiet: bool,
    #[command(flatten)]
    pub memory: MemoryArgs,
}

/// What a resumed reference starts from.
struct EarlierRun {
    image: ImageBuf,
    integrator: String,
    seed: u64,
    spp: u32,
    samples: u64,
    elapsed: f64,
    segments: u32,
}

fn read_earlier_run(path: &Path, scene: &Scene) -> anyhow::Result<EarlierRun> {
    let meta = read_exr_metadata(path).with_context(|| format!("cannot resume from {}", path.display()))?;
    let field = |key: &str| -> anyhow::Result<&str> {
        lookup(&meta, key).with_context(|| {
            format!(
                "{}: no {key} in its metadata (expected a checkpoint written by `hslt reference`)",
                path.display()
            )
        })
    };
    let number = |key: &str| -> anyhow::Result<f64> {
        let v = field(key)?;
        v.parse::<f64>().ok().filter(|x| x.is_finite() && *x >= 0.0).with_context(|| {
            format!("{}: metadata {key} = {v:?} (expected a non-negative number)", path.display())
        })
    };
    let image = load_reference(path, scene)?;
    Ok(EarlierRun {
        image,
        integrator: field("hslt.integrator")?.to_string(),
        seed: number("hslt.seed")? as u64,
        spp: number("hslt.spp")? as u32,
        samples: number("hslt.samples")? as u64,
        elapsed: number("hslt.elapsed_seconds")?,
        segments: lookup(&meta, "hslt.reference.segments").and_then(|v| v.parse().ok()).unwrap_or(1),
    })
}

/// The mean of two estimates of the same image weighted by their work (samples or mutations):
/// exactly the image one run of both together would give.
fn combine(earlier: &ImageBuf, earlier_samples: u64, now: &ImageBuf, now_samples: u64) -> ImageBuf {
    let total = (earlier_samples + now_samples) as f64;
    if total == 0.0 {
        return now.clone();
    }
    let (a, b) = (earlier_samples as f64 / total, now_samples as f64 / total);
    let mut out = now.clone();
    for (o, (&x, &y)) in out.data.iter_mut().zip(earlier.data.iter().zip(&now.data)) {
        *o = (a * x as f64 + b * y as f64) as f32;
    }
    out
}

/// Everything a checkpoint's metadata records besides the render's own.
struct CheckpointInfo<'a> {
    scene: &'a Scene,
    integrator: &'a str,
    seed: u64,
    limits: DepthLimits,
    threads: usize,
    segments: u32,
}

impl CheckpointInfo<'_> {
    /// Writes the combined image of the earlier runs and this one so far.
    fn write(
        &self,
        path: &Path,
        earlier: Option<&EarlierRun>,
        now: &ImageBuf,
        stats: &RenderStats,
        extra: &[(String, String)],
        complete: bool,
    ) -> anyhow::Result<()> {
        let (image, spp, samples, elapsed) = match earlier {
            Some(e) => (
                combine(&e.image, e.samples, now, stats.samples),
                e.spp + stats.min_spp,
                e.samples + stats.samples,
                e.elapsed + stats.elapsed.as_secs_f64(),
            ),
            None => (now.clone(), stats.min_spp, stats.samples, stats.elapsed.as_secs_f64()),
        };
        let total =
            RenderStats { samples, min_spp: spp, elapsed: Duration::from_secs_f64(elapsed), ..stats.clone() };
        let options = RenderOptions { seed: self.seed, ..Default::default() };
        let mut meta = metadata(self.scene, self.integrator, &options, self.limits, self.threads, &total);
        meta.push(("hslt.reference.segments".into(), self.segments.to_string()));
        meta.push(("hslt.reference.complete".into(), complete.to_string()));
        meta.extend(extra.iter().cloned());
        write_image(path, &image, &meta)
    }
}

pub fn run_reference(args: ReferenceArgs) -> anyhow::Result<i32> {
    if args.output.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref()
        != Some("exr")
    {
        bail!(
            "{}: a reference must be an .exr file (it carries the sample count for --resume)",
            args.output.display()
        );
    }
    if let Some(t) = args.time {
        check_seconds("--time", t)?;
    }
    check_seconds("--checkpoint-minutes", args.checkpoint_minutes)?;
    if args.spp == Some(0) {
        bail!("--spp must be at least 1");
    }
    args.memory.apply();
    let scene = load(&args.scene, parse_accel(&args.accel)?)?;
    let earlier = if args.resume {
        if !args.output.is_file() {
            bail!(
                "--resume: {} does not exist (run once without --resume to start it)",
                args.output.display()
            );
        }
        let e = read_earlier_run(&args.output, &scene)?;
        if let Some(name) = &args.integrator {
            if IntegratorKind::parse(name).map(|k| k.name())
                != IntegratorKind::parse(&e.integrator).map(|k| k.name())
            {
                bail!("{}: was rendered with '{}', not '{name}'", args.output.display(), e.integrator);
            }
        }
        if let Some(seed) = args.seed.filter(|&s| s != e.seed) {
            bail!("{}: was rendered with seed {}, not {seed}", args.output.display(), e.seed);
        }
        Some(e)
    } else {
        None
    };
    let kind_name = match (&earlier, &args.integrator) {
        (Some(e), _) => e.integrator.clone(),
        (None, Some(name)) => name.clone(),
        (None, None) => scene.integrator.kind.clone(),
    };
    let kind = IntegratorKind::parse(&kind_name).map_err(anyhow::Error::msg)?;
    let seed = earlier.as_ref().map(|e| e.seed).or(args.seed).unwrap_or(REFERENCE_DEFAULT_SEED);
    // Pixel integrators continue their per-pixel streams after the samples already taken; integrators
    // without spp get the segment count, which they mix into their seeds (RenderOptions::first_sample).
    let first_sample = earlier.as_ref().map(|e| if e.spp > 0 { e.spp } else { e.segments }).unwrap_or(0);
    let limits = DepthLimits::of_scene(&scene);
    let integrator = registry::make(kind, limits, scene.integrator.hide_emitters);
    install_ctrlc_handler("finishing the current work and writing the outputs so far");
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let info = CheckpointInfo {
        scene: &scene,
        integrator: kind.name(),
        seed,
        limits,
        threads,
        segments: earlier.as_ref().map_or(1, |e| e.segments + 1),
    };
    let (output, over_memory) = args.memory.watch(|| {
        std::thread::scope(|scope| {
            // The sink must be 'static; it hands snapshots to this scope through a channel instead of
            // borrowing the scene, and a writer thread here saves them while the render goes on.
            let (send, receive) = std::sync::mpsc::channel::<Snapshot>();
            let writer = scope.spawn(|| {
                for s in receive {
                    let stats = RenderStats {
                        samples: s.samples,
                        min_spp: s.spp,
                        elapsed: s.elapsed,
                        ..Default::default()
                    };
                    if let Err(e) =
                        info.write(&args.output, earlier.as_ref(), &s.image, &stats, &s.extra, false)
                    {
                        // The render goes on: the next checkpoint or the final write may still succeed.
                        eprintln!("warning: checkpoint not written: {e:#}");
                    }
                }
            });
            let interval = Duration::from_secs_f64(args.checkpoint_minutes * 60.0);
            let end = args.time.map(Duration::from_secs_f64);
            // Without a time limit the checkpoints run on for as long as 10 000 intervals.
            let times: Vec<Duration> = (1..=10_000u32)
                .map(|k| interval * k)
                .take_while(|t| end.is_none_or(|end| *t < end))
                .collect();
            let sink = move |s: &Snapshot| {
                let _ = send.send(s.clone());
            };
            let options = RenderOptions {
                spp: args.spp.or(if args.time.is_some() { None } else { Some(scene.spp) }),
                time_limit: end,
                seed,
                progress: !args.quiet,
                snapshots: Some(SnapshotHook::images(times, sink)),
                first_sample,
                ..Default::default()
            };
            let output = pool.install(|| integrator.render(&scene, &options, &CANCEL));
            // Dropping the options drops the sink and with it the sender, which ends the writer's loop.
            drop(options);
            let _ = writer.join();
            output
        })
    });
    let stats = &output.stats;
    info.write(
        &args.output,
        earlier.as_ref(),
        &output.film.to_image(),
        stats,
        &output.metadata,
        !stats.interrupted,
    )
    .with_context(|| format!("cannot write the reference {}", args.output.display()))?;
    if !args.quiet {
        let total_spp = earlier.as_ref().map_or(0, |e| e.spp) + stats.min_spp;
        eprintln!(
            "{}: {} spp in this run ({} in total) in {:.1} s with {}{}",
            args.output.display(),
            stats.min_spp,
            total_spp,
            stats.elapsed.as_secs_f64(),
            kind.name(),
            if stats.interrupted { " (interrupted; continue with --resume)" } else { "" }
        );
    }
    if let Some(over) = over_memory {
        return Err(MemoryArgs::exceeded(over, &args.output.display().to_string()));
    }
    Ok(if stats.interrupted { 130 } else { 0 })
}
