//! `hslt compare` (error against time for several integrators, written as a report folder) and
//! `hslt reference` (long checkpointed renders that can be resumed). Both drive integrators only
//! through `Integrator::render` and its snapshot hook, so every integrator `IntegratorKind` knows works.

use super::{load, metadata, parse_accel, parse_hslt_direction, thread_pool, SceneArgs};
use crate::image::{read_exr_metadata, read_image, write_image, ImageBuf, Metadata};
use crate::integrators::{self, DepthLimits, IntegratorKind};
use crate::render::{RenderOptions, RenderStats, Snapshot, SnapshotHook};
use crate::report::html::{self, IntegratorEntry, Page};
use crate::report::{self, metrics, plot, ErrorRow, Metric};
use crate::scene::Scene;
use anyhow::{bail, Context};
use clap::Args;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Seed `reference` uses unless told otherwise: different from the other commands' default 0, so a
/// reference is never made of the very samples the compared renders take.
pub const REFERENCE_DEFAULT_SEED: u64 = 1_000_003;

#[derive(Args, Debug)]
pub struct CompareArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Reference image (EXR, or any format we read) of the scene's film size.
    #[arg(long)]
    pub reference: PathBuf,
    /// Integrators to compare, comma-separated (any name `--integrator` accepts), run one after another.
    #[arg(long, value_delimiter = ',', required = true)]
    pub integrators: Vec<String>,
    /// Wall time for each integrator.
    #[arg(long, value_name = "SECONDS")]
    pub time: f64,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Snapshots per integrator, log-spaced from a hundredth of --time to --time.
    #[arg(long, default_value_t = 12)]
    pub snapshots: usize,
    /// Metric the plot shows: relmse, rmse or mae (the CSV has all of them).
    #[arg(long, default_value = "relmse")]
    pub metric: String,
    /// ε of the relative MSE, (x − r)² / (r² + ε).
    #[arg(long, default_value_t = metrics::DEFAULT_REL_EPSILON)]
    pub epsilon: f64,
    /// Worker threads (0 = all cores), the same pool for every integrator.
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Seed of all random streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// HSLT: the end the half-vector mutation's walk traces from (see `render --hslt-direction`).
    #[arg(long, value_name = "DIR", default_value = "camera", value_parser = ["camera", "light", "rule"])]
    pub hslt_direction: String,
    /// Shortest path rendered, in segments (see `render --min-depth`): 3 compares the Metropolis
    /// methods' chains alone, on indirect light, against a reference rendered with the same value.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub min_depth: i32,
    /// Ray-query backend.
    #[arg(long, default_value = "embree")]
    pub accel: String,
    /// No progress bars or summary.
    #[arg(short, long)]
    pub quiet: bool,
}

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
}

/// Set by our Ctrl-C handler: the current render finishes its work in progress and the outputs
/// are written with what exists.
static CANCEL: AtomicBool = AtomicBool::new(false);

fn install_ctrlc_handler() {
    let _ = ctrlc::set_handler(|| {
        if CANCEL.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("\ninterrupted: finishing the current work and writing the outputs so far");
    });
}

fn check_seconds(flag: &str, v: f64) -> anyhow::Result<()> {
    if !(v > 0.0 && v.is_finite()) {
        bail!("{flag} must be a positive number, not {v}");
    }
    Ok(())
}

fn depth_limits(scene: &Scene) -> DepthLimits {
    DepthLimits { max_depth: scene.integrator.max_depth, rr_depth: scene.integrator.rr_depth }
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

pub fn run_compare(args: CompareArgs) -> anyhow::Result<i32> {
    check_seconds("--time", args.time)?;
    if args.snapshots < 2 {
        bail!("--snapshots must be at least 2 (the first and the last point of each line)");
    }
    if !(args.epsilon > 0.0 && args.epsilon.is_finite()) {
        bail!("--epsilon must be a positive number");
    }
    let metric = Metric::parse(&args.metric).map_err(anyhow::Error::msg)?;
    if args.min_depth < 1 {
        bail!("--min-depth must be at least 1");
    }
    // Every name is checked before the first long render starts.
    let mut kinds: Vec<(String, IntegratorKind)> = Vec::new();
    for name in &args.integrators {
        let name = name.trim();
        let kind = IntegratorKind::parse(name).map_err(anyhow::Error::msg)?;
        if kinds.iter().any(|(n, _)| report::file_stem(n) == report::file_stem(name)) {
            bail!("--integrators names '{name}' twice");
        }
        kinds.push((name.to_string(), kind));
    }
    let scene = load(&args.scene, parse_accel(&args.accel)?)?;
    let reference = load_reference(&args.reference, &scene)?;
    if let Ok(meta) = read_exr_metadata(&args.reference) {
        if lookup(&meta, "hslt.seed") == Some(&args.seed.to_string()) {
            eprintln!(
                "warning: {} was rendered with the same seed ({}) as this comparison: an integrator that is \
                 also the reference's takes the reference's own samples and looks better than it is",
                args.reference.display(),
                args.seed
            );
        }
        let reference_min_depth = lookup(&meta, "hslt.min_depth").unwrap_or("1");
        if reference_min_depth != args.min_depth.to_string() {
            eprintln!(
                "warning: {} was rendered with --min-depth {reference_min_depth}, this comparison uses {}: \
                 the images hold different light",
                args.reference.display(),
                args.min_depth
            );
        }
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the output folder {}", args.out.display()))?;
    install_ctrlc_handler();
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let total = Duration::from_secs_f64(args.time);
    let times = report::log_spaced_times(total, args.snapshots);
    let limits = depth_limits(&scene);
    if limits.max_depth > 0 && args.min_depth > limits.max_depth {
        bail!("--min-depth {} is above the scene's max_depth ({})", args.min_depth, limits.max_depth);
    }
    let mut settings = integrators::IntegratorSettings::new(limits, scene.integrator.hide_emitters);
    settings.min_depth = args.min_depth;
    settings.mutation.halfvector.direction = parse_hslt_direction(&args.hslt_direction)?;
    let reference = Arc::new(reference);

    let mut rows: Vec<ErrorRow> = Vec::new();
    let mut finals: Vec<(String, ImageBuf)> = Vec::new();
    let mut interrupted = false;
    for (name, kind) in &kinds {
        if !args.quiet {
            eprintln!("{name}: rendering for {} s", args.time);
        }
        let integrator = integrators::make_with(*kind, &settings);
        let snapshot_rows: Arc<Mutex<Vec<ErrorRow>>> = Arc::default();
        let sink = {
            let (rows, reference, name, eps) =
                (snapshot_rows.clone(), reference.clone(), name.clone(), args.epsilon);
            move |s: &Snapshot| {
                // The reference was checked against the film size, so this only fails on a broken
                // integrator; its snapshot is then left out rather than stopping the comparison.
                match metrics::compute(&s.image, &reference, eps) {
                    Ok(m) => rows.lock().unwrap_or_else(|e| e.into_inner()).push(ErrorRow {
                        integrator: name.clone(),
                        elapsed: s.elapsed,
                        samples: s.samples,
                        spp: s.spp,
                        metrics: m,
                        acceptance_rate: report::acceptance_rate(&s.extra),
                    }),
                    Err(e) => eprintln!("warning: {name}: snapshot at {:?} skipped: {e:#}", s.elapsed),
                }
            }
        };
        // The last point is the final output itself (the loop may stop just before the budget).
        let options = RenderOptions {
            time_limit: Some(total),
            seed: args.seed,
            progress: !args.quiet,
            snapshots: Some(SnapshotHook { times: times[..times.len() - 1].to_vec(), sink: Arc::new(sink) }),
            ..Default::default()
        };
        let output = pool.install(|| integrator.render(&scene, &options, &CANCEL));
        let image = output.film.to_image();
        let mut own_rows = std::mem::take(&mut *snapshot_rows.lock().unwrap_or_else(|e| e.into_inner()));
        own_rows.push(ErrorRow {
            integrator: name.clone(),
            elapsed: output.stats.elapsed,
            samples: output.stats.samples,
            spp: output.stats.min_spp,
            metrics: metrics::compute(&image, &reference, args.epsilon)
                .with_context(|| format!("{name}: the final image does not match the reference"))?,
            acceptance_rate: report::acceptance_rate(&output.metadata),
        });
        rows.extend(own_rows);
        let mut meta = metadata(&scene, name, &options, limits, threads, &output.stats);
        if args.min_depth > 1 {
            meta.push(("hslt.min_depth".into(), args.min_depth.to_string()));
        }
        meta.extend(output.metadata);
        let exr = args.out.join(format!("{}.exr", report::file_stem(name)));
        write_image(&exr, &image, &meta)?;
        finals.push((name.clone(), image));
        if output.stats.interrupted {
            interrupted = true;
            break;
        }
    }

    write_report(&args, metric, threads, &reference, &rows, &finals)?;
    if !args.quiet {
        print_compare_summary(&rows, &finals, metric);
        eprintln!("wrote {}", args.out.join("index.html").display());
    }
    Ok(if interrupted { 130 } else { 0 })
}

/// The final (last) row of each integrator.
fn final_rows<'a>(rows: &'a [ErrorRow], finals: &'a [(String, ImageBuf)]) -> Vec<&'a ErrorRow> {
    finals.iter().filter_map(|(name, _)| rows.iter().rev().find(|r| &r.integrator == name)).collect()
}

fn print_compare_summary(rows: &[ErrorRow], finals: &[(String, ImageBuf)], metric: Metric) {
    eprintln!("{:<12} {:>10} {:>14} {:>14}", "integrator", "seconds", "samples", metric.label());
    for r in final_rows(rows, finals) {
        eprintln!(
            "{:<12} {:>10.2} {:>14} {:>14.4e}",
            r.integrator,
            r.elapsed.as_secs_f64(),
            r.samples,
            metric.of(&r.metrics)
        );
    }
}

fn write_report(
    args: &CompareArgs,
    metric: Metric,
    threads: usize,
    reference: &ImageBuf,
    rows: &[ErrorRow],
    finals: &[(String, ImageBuf)],
) -> anyhow::Result<()> {
    let out = &args.out;
    let no_meta = Metadata::new();
    report::write_atomic(&out.join("error.csv"), report::error_csv(rows).as_bytes())?;
    let series: Vec<plot::Series> = finals
        .iter()
        .map(|(name, _)| plot::Series {
            name: name.clone(),
            points: rows
                .iter()
                .filter(|r| &r.integrator == name)
                .map(|r| (r.elapsed.as_secs_f64(), metric.of(&r.metrics)))
                .collect(),
        })
        .collect();
    let scene_name = args.scene.scene.display().to_string();
    let title = format!("{} against time: {scene_name}", metric.label());
    report::write_atomic(
        &out.join("error.svg"),
        plot::error_plot_svg(&series, metric.label(), &title)?.as_bytes(),
    )?;
    write_image(&out.join("error.png"), &plot::error_plot_image(&series, metric.label(), &title)?, &no_meta)?;

    let (w, h) = (reference.width, reference.height);
    write_image(&out.join("reference.png"), reference, &no_meta)?;
    let maps: Vec<Vec<f64>> = finals
        .iter()
        .map(|(_, img)| metrics::relative_error_map(img, reference, args.epsilon))
        .collect::<anyhow::Result<_>>()?;
    let regions = html::worst_regions(&maps, w, h, (w.min(h) / 8).max(8), 3);
    let mut reference_crops = Vec::new();
    for (i, r) in regions.iter().enumerate() {
        let file = format!("reference-crop{i}.png");
        write_image(&out.join(&file), &html::crop(reference, *r), &no_meta)?;
        reference_crops.push(file);
    }
    let finals_by_name = final_rows(rows, finals);
    let mut entries = Vec::new();
    for (((name, img), map), row) in finals.iter().zip(&maps).zip(finals_by_name) {
        let stem = report::file_stem(name);
        let image = format!("{stem}.png");
        write_image(&out.join(&image), img, &no_meta)?;
        let error_map = format!("{stem}-error.png");
        write_image(&out.join(&error_map), &html::false_colour(map, w, h), &no_meta)?;
        let mut crops = Vec::new();
        for (i, r) in regions.iter().enumerate() {
            let file = format!("{stem}-crop{i}.png");
            write_image(&out.join(&file), &html::crop(img, *r), &no_meta)?;
            crops.push(file);
        }
        let acceptance = row.acceptance_rate.map(|a| format!(", acceptance {a:.3}")).unwrap_or_default();
        entries.push(IntegratorEntry {
            name: name.clone(),
            image,
            exr: format!("{stem}.exr"),
            error_map,
            crops,
            summary: format!(
                "{:.1} s, {} samples, relMSE {:.3e}, RMSE {:.3e}, MAE {:.3e}{acceptance}",
                row.elapsed.as_secs_f64(),
                row.samples,
                row.metrics.rel_mse,
                row.metrics.rmse,
                row.metrics.mae
            ),
        });
    }
    let page = Page {
        title: format!("hslt compare: {scene_name}"),
        setup: format!(
            "Scene {scene_name}, reference {}, {} s per integrator on {threads} threads, seed {}, {}x{} pixels.",
            args.reference.display(),
            args.time,
            args.seed,
            w,
            h
        ),
        reference_image: "reference.png".into(),
        reference_crops,
        regions,
        integrators: entries,
        plot_svg: "error.svg".into(),
        csv: "error.csv".into(),
        metric_note: format!(
            "The plot shows the {}; relative MSE is the mean over pixels and colour channels of (x − r)² / (r² + ε) \
             with ε = {}.",
            metric.label(),
            args.epsilon
        ),
    };
    report::write_atomic(&out.join("index.html"), html::render_page(&page).as_bytes())
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
    let limits = depth_limits(&scene);
    let integrator = integrators::make(kind, limits, scene.integrator.hide_emitters);
    install_ctrlc_handler();
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
    let output = std::thread::scope(|scope| {
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
                if let Err(e) = info.write(&args.output, earlier.as_ref(), &s.image, &stats, &s.extra, false)
                {
                    // The render goes on: the next checkpoint or the final write may still succeed.
                    eprintln!("warning: checkpoint not written: {e:#}");
                }
            }
        });
        let interval = Duration::from_secs_f64(args.checkpoint_minutes * 60.0);
        let end = args.time.map(Duration::from_secs_f64);
        // Without a time limit the checkpoints run on for as long as 10 000 intervals.
        let times: Vec<Duration> =
            (1..=10_000u32).map(|k| interval * k).take_while(|t| end.is_none_or(|end| *t < end)).collect();
        let sink = move |s: &Snapshot| {
            let _ = send.send(s.clone());
        };
        let options = RenderOptions {
            spp: args.spp.or(if args.time.is_some() { None } else { Some(scene.spp) }),
            time_limit: end,
            seed,
            progress: !args.quiet,
            snapshots: Some(SnapshotHook { times, sink: Arc::new(sink) }),
            first_sample,
        };
        let output = pool.install(|| integrator.render(&scene, &options, &CANCEL));
        // Dropping the options drops the sink and with it the sender, which ends the writer's loop.
        drop(options);
        let _ = writer.join();
        output
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
    Ok(if stats.interrupted { 130 } else { 0 })
}
