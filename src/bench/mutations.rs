//! `hslt bench hslt`: HSLT mutations per second on a scene's stationary paths (drawn from a BDPT
//! seeding pass), with the Newton corrector's ray casts batched per pass (one query for the three
//! candidate step sizes) and cast one at a time, measured side by side on the same proposals, with
//! the walk traced from the chosen end (`--direction`) and what the proposals gave (acceptance, failures).

use crate::integrators::{Bdpt, DepthLimits};
use crate::manifold::WalkSettings;
use crate::metropolis::mutations::halfvector::{
    applicable, HalfVectorMutation, HalfVectorParams, TraceDirection,
};
use crate::metropolis::{Failure, Mutation, MutationStats, PathContext, PathSeeds, PathState};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::luminance;
use std::fmt::Write as _;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

/// One timed pass over the starting paths.
struct Pass {
    seconds: f64,
    rays: u64,
    built: usize,
    /// Σ min(1, acceptance ratio) over the proposals: the chain's expected acceptance from these starts.
    acceptance_sum: f64,
    stats: MutationStats,
}

fn run_pass(
    scene: &Scene,
    bdpt: &Bdpt,
    starts: &[PathState],
    batch_rays: bool,
    direction: TraceDirection,
) -> Pass {
    let defaults = HalfVectorParams::default();
    let params =
        HalfVectorParams { walk: WalkSettings { batch_rays, ..defaults.walk }, direction, ..defaults };
    let mut mutation = HalfVectorMutation::new(params);
    let mut ctx = PathContext::new(scene, bdpt);
    // The same stream in both modes: the same targets, so the same walks, differ only in ray casting.
    let mut rng = Sampler::new(0x4853, 0, 0);
    let start = Instant::now();
    let mut built = 0;
    let mut acceptance_sum = 0.0;
    let mut stats = MutationStats::default();
    for x in starts {
        match mutation.propose(x, &mut ctx, &mut rng, &mut stats) {
            Ok(p) => {
                built += 1;
                let ratio =
                    luminance(p.state.contribution) as f64 * p.t_ratio / luminance(x.contribution) as f64;
                if ratio.is_finite() {
                    acceptance_sum += ratio.min(1.0);
                }
            }
            Err(Failure::Failed(reason)) => *stats.failed.entry(reason).or_insert(0) += 1,
            Err(Failure::NotApplicable) => {}
        }
    }
    Pass { seconds: start.elapsed().as_secs_f64(), rays: ctx.counters.rays, built, acceptance_sum, stats }
}

/// Proposes the HSLT mutation once from each of `proposals` stationary paths the mutation applies to,
/// `repeats` times per mode (alternating, on the calling thread), and reports the medians.
pub fn bench_hslt(
    scene: &Scene,
    proposals: usize,
    repeats: usize,
    direction: TraceDirection,
) -> anyhow::Result<String> {
    let limits = DepthLimits { max_depth: scene.integrator.max_depth, rr_depth: scene.integrator.rr_depth };
    let bdpt = Bdpt::new(limits, scene.integrator.hide_emitters);
    let pixels = scene.film.width * scene.film.height;
    let seeds = PathSeeds::run(scene, &bdpt, 1, (4 * pixels).clamp(16_384, 1 << 20), &AtomicBool::new(false));
    if seeds.candidates() == 0 {
        anyhow::bail!("the seeding pass found no light-carrying path");
    }
    let mut rng = Sampler::new(0x5EED, 0, 0);
    let mut starts = Vec::with_capacity(proposals);
    for _ in 0..proposals.saturating_mul(200) {
        if starts.len() == proposals {
            break;
        }
        if let Some(x) = seeds.draw(scene, &bdpt, 1, rng.next_f64()) {
            if applicable(&x.vertices) {
                starts.push(x);
            }
        }
    }
    if starts.is_empty() {
        anyhow::bail!("no path of this scene has a glossy inner vertex for the half-vector mutation");
    }
    let mut batched = Vec::new();
    let mut single = Vec::new();
    for _ in 0..repeats.max(1) {
        batched.push(run_pass(scene, &bdpt, &starts, true, direction));
        single.push(run_pass(scene, &bdpt, &starts, false, direction));
    }
    let median = |passes: &mut Vec<Pass>| {
        passes.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
        passes.swap_remove(passes.len() / 2)
    };
    let (b, s) = (median(&mut batched), median(&mut single));
    let mut out = String::new();
    let _ = writeln!(
        out,
        "HSLT proposals from {} stationary paths, one thread, median of {repeats}, traced from: {}",
        starts.len(),
        direction.name()
    );
    let _ = writeln!(
        out,
        "{:<22} {:>14} {:>12} {:>10} {:>12}",
        "corrector rays", "mutations/s", "Mrays/s", "built", "rays/mut."
    );
    for (name, p) in [("batched per pass", &b), ("one at a time", &s)] {
        let _ = writeln!(
            out,
            "{name:<22} {:>14.0} {:>12.2} {:>10} {:>12.1}",
            starts.len() as f64 / p.seconds,
            p.rays as f64 / p.seconds / 1e6,
            p.built,
            p.rays as f64 / starts.len() as f64
        );
    }
    let _ = writeln!(out, "speed-up of batched over single-ray casts: {:.3}x", s.seconds / b.seconds);
    let n = starts.len() as f64;
    let sum = |what: &str| b.stats.sums.get(what).copied().unwrap_or(0.0);
    let _ = writeln!(
        out,
        "acceptance {:.4}, built {:.4}, mean Newton iterations {:.2}, traced from the light {:.3}",
        b.acceptance_sum / n,
        b.built as f64 / n,
        sum("newton_iterations") / sum("converged_walks").max(1.0),
        sum("traced_from_light") / n
    );
    let mut failures: Vec<_> = b.stats.failed.iter().collect();
    failures.sort_by(|x, y| y.1.cmp(x.1));
    let failures: Vec<String> = failures.iter().map(|(r, c)| format!("{r} {:.4}", **c as f64 / n)).collect();
    let _ = writeln!(out, "failures per proposal: {}", failures.join(", "));
    Ok(out)
}
