//! `hslt bench`: throughput benchmarks that print ratios measured side by side in one run (path tracer,
//! ray-query backends, integrators, HSLT mutations), never timed tests.

use super::{load, parse_accel, parse_hslt_direction, thread_pool, SceneArgs};
use crate::accel::AccelKind;
use crate::registry::{self, IntegratorKind};
use crate::render::{DepthLimits, RenderOptions, RenderStats};
use clap::{Args, Subcommand};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

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
    /// Worker threads (0 = all cores), for us and for Mitsuba.
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Also time our whole `hslt render --integrator pt` process against Mitsuba 3's render of the same
    /// file, pair by pair, with these variants (an empty list skips the comparison).
    #[arg(long, value_name = "LIST", default_value = "llvm_ad_rgb,scalar_rgb")]
    pub mitsuba_variants: String,
    /// Python interpreter that imports Mitsuba 3 [default: $HSLT_MITSUBA_PYTHON, else python3]; when it
    /// cannot, the comparison is skipped with the reason.
    #[arg(long, value_name = "PATH")]
    pub mitsuba_python: Option<std::path::PathBuf>,
    /// Pairs of runs for the comparison with Mitsuba; medians are reported.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
}

pub(super) fn run_bench(args: BenchArgs) -> anyhow::Result<i32> {
    let mut scene = load(&args.scene, parse_accel(&args.accel)?)?;
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    let integrator =
        registry::make(IntegratorKind::Path, DepthLimits::of_scene(&scene), scene.integrator.hide_emitters);
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
    compare_with_mitsuba(&args, &scene)?;
    Ok(0)
}

/// Our whole render process against Mitsuba's render alone, alternating, medians of `args.repeats`.
fn compare_with_mitsuba(args: &BenchArgs, scene: &crate::scene::Scene) -> anyhow::Result<()> {
    use crate::bench::median;
    use crate::bench::mitsuba::{probe, python_for_mitsuba, run_mitsuba, run_ours};
    let wanted: Vec<&str> =
        args.mitsuba_variants.split(',').map(str::trim).filter(|v| !v.is_empty()).collect();
    if wanted.is_empty() {
        return Ok(());
    }
    let python = python_for_mitsuba(args.mitsuba_python.as_deref());
    let mut variants = Vec::new();
    for variant in wanted {
        match probe(&python, variant) {
            Ok(_) => variants.push(variant),
            Err(why) => println!("mitsuba {variant:<12} skipped: {why}"),
        }
    }
    if variants.is_empty() {
        return Ok(());
    }
    let scratch = std::env::temp_dir().join(format!("hslt-bench-pt-{}", std::process::id()));
    std::fs::create_dir_all(&scratch)?;
    let (path, defines) = (&args.scene.scene, &args.scene.define);
    let mut ours = Vec::new();
    let mut theirs: Vec<Vec<crate::bench::mitsuba::MitsubaRun>> = vec![Vec::new(); variants.len()];
    let result = (|| -> anyhow::Result<()> {
        for _ in 0..args.repeats.max(1) {
            ours.push(run_ours(path, defines, args.spp, args.threads, &scratch)?);
            for (runs, variant) in theirs.iter_mut().zip(&variants) {
                runs.push(run_mitsuba(&python, variant, path, defines, args.spp, args.threads)?);
            }
        }
        Ok(())
    })();
    // The scratch directory holds only our render's image and statistics.
    let _ = std::fs::remove_dir_all(&scratch);
    result?;
    let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
    let our_secs = median(&mut ours.iter().map(|r| r.process_seconds).collect::<Vec<_>>());
    let our_peak = ours.iter().map(|r| r.peak_memory_bytes).max().unwrap_or(0);
    let samples = ours[0].samples;
    println!();
    println!(
        "side by side, {} x {} at {} spp, {} pairs (medians; Mitsuba {} via {})",
        scene.film.width,
        scene.film.height,
        args.spp,
        ours.len(),
        theirs[0][0].version,
        python.display()
    );
    println!("{:<34} {:>9} {:>12} {:>10}", "", "seconds", "samples/s", "peak MiB");
    println!(
        "{:<34} {:>9.2} {:>12.0} {:>10.0}",
        "hslt pt, whole process",
        our_secs,
        samples as f64 / our_secs,
        mib(our_peak)
    );
    for (runs, variant) in theirs.iter().zip(&variants) {
        let render = median(&mut runs.iter().map(|r| r.render_seconds).collect::<Vec<_>>());
        let first = median(&mut runs.iter().map(|r| r.first_render_seconds).collect::<Vec<_>>());
        let setup = median(&mut runs.iter().map(|r| r.import_seconds + r.load_seconds).collect::<Vec<_>>());
        let peak = runs.iter().map(|r| r.peak_memory_bytes).max().unwrap_or(0);
        let their_samples = runs[0].samples;
        println!(
            "{:<34} {:>9.2} {:>12.0} {:>10.0}",
            format!("mitsuba {variant}, render alone"),
            render,
            their_samples as f64 / render,
            mib(peak)
        );
        println!("{:<34} {:>9.2}", "  first render (JIT unless cached)", first);
        println!("{:<34} {:>9.2}", "  import and scene load", setup);
        println!(
            "  ratio: hslt whole process is {:.2}x the speed of its render alone ({:.2}x of its first), \
             peak memory {:.2}x",
            render / our_secs,
            first / our_secs,
            our_peak as f64 / peak.max(1) as f64
        );
    }
    Ok(())
}

pub(super) fn run_bench_integrators(args: BenchIntegratorsArgs) -> anyhow::Result<i32> {
    let scene = load(&args.scene, AccelKind::Embree)?;
    let pool = thread_pool(args.threads)?;
    let limits = DepthLimits::of_scene(&scene);
    let kinds = args
        .integrators
        .split(',')
        .map(|n| IntegratorKind::parse(n.trim()).map_err(anyhow::Error::msg))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let never = AtomicBool::new(false);
    let options = RenderOptions { spp: Some(args.spp.max(1)), seed: 1, ..Default::default() };
    let integrators: Vec<_> =
        kinds.iter().map(|&k| registry::make(k, limits, scene.integrator.hide_emitters)).collect();
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

pub(super) fn run_bench_hslt(args: BenchHsltArgs) -> anyhow::Result<i32> {
    let scene = load(&args.scene, AccelKind::Embree)?;
    let direction = parse_hslt_direction(&args.direction)?;
    print!("{}", crate::bench::bench_hslt(&scene, args.proposals, args.repeats, direction)?);
    Ok(0)
}

pub(super) fn run_bench_rays(args: BenchRaysArgs) -> anyhow::Result<i32> {
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
