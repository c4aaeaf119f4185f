//! `hslt compare`: several integrators for the same wall time, their error against a reference at
//! snapshot times, written as a report folder (plots, tables, images). It drives integrators only
//! through `Integrator::render` and its snapshot hook, so every integrator `IntegratorKind` knows works.

use super::render::metadata;
use super::{
    check_seconds, install_ctrlc_handler, load, load_reference, lookup, parse_accel, parse_hslt_direction,
    thread_pool, SceneArgs, CANCEL,
};
use crate::image::{read_exr_metadata, write_image, ImageBuf, Metadata};
use crate::registry::{self, IntegratorKind};
use crate::render::{DepthLimits, RenderOptions, Snapshot, SnapshotHook};
use crate::report::html::{self, IntegratorEntry, Page};
use crate::report::{self, metrics, plot, ErrorRow, Metric};
use anyhow::{bail, Context};
use clap::Args;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

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
    /// HSLT: what the half-vector mutation moves, `sub` or `whole` (see `render --hslt-chains`).
    #[arg(long, value_name = "WHICH", default_value = "whole", value_parser = ["whole", "sub"])]
    pub hslt_chains: String,
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
    install_ctrlc_handler("finishing the current work and writing the outputs so far");
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let total = Duration::from_secs_f64(args.time);
    let times = report::log_spaced_times(total, args.snapshots);
    let limits = DepthLimits::of_scene(&scene);
    if limits.max_depth > 0 && args.min_depth > limits.max_depth {
        bail!("--min-depth {} is above the scene's max_depth ({})", args.min_depth, limits.max_depth);
    }
    let mut settings = registry::IntegratorSettings::new(limits, scene.integrator.hide_emitters);
    settings.min_depth = args.min_depth;
    settings.mutation.halfvector.direction = parse_hslt_direction(&args.hslt_direction)?;
    settings.mutation.halfvector.sub_chains = args.hslt_chains == "sub";
    let reference = Arc::new(reference);

    let mut rows: Vec<ErrorRow> = Vec::new();
    let mut finals: Vec<(String, ImageBuf)> = Vec::new();
    let mut interrupted = false;
    for (name, kind) in &kinds {
        if !args.quiet {
            eprintln!("{name}: rendering for {} s", args.time);
        }
        let integrator = registry::make_with(*kind, &settings);
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
            snapshots: Some(SnapshotHook::images(times[..times.len() - 1].to_vec(), sink)),
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
