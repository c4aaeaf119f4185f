//! `hslt bench hslt`: HSLT mutations per second on a scene's stationary paths (drawn from a BDPT
//! seeding pass), with the Newton corrector's step candidates traced one by one (the default) or three
//! per pass (batched into one query, or cast one at a time), measured side by side on the same proposals, with
//! the walk traced from the chosen end (`--direction`) and what the proposals gave (acceptance, failures);
//! then the proposals' forward walks alone, G walks in flight sharing each corrector query (issue #7).

use super::median;
use crate::accel::{Hit, RayQuery};
use crate::geometry::Ray;
use crate::integrators::Bdpt;
use crate::manifold::{walk_many, walk_many_through, WalkJob, WalkSettings};
use crate::metropolis::mutations::halfvector::{
    applicable, HalfVectorMutation, HalfVectorParams, TraceDirection,
};
use crate::metropolis::{Failure, Mutation, MutationStats, PathContext, PathSeeds, PathState};
use crate::path::Vertex;
use crate::render::DepthLimits;
use crate::sampling::Sampler;
use crate::scene::Scene;
use glam::DVec2;
use std::fmt::Write as _;
use std::hash::{Hash, Hasher};
use std::sync::atomic::AtomicBool;
use std::sync::Mutex;
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

impl Pass {
    /// The table columns of a pass over `n` items: items/s, Mrays/s, built, rays per item.
    fn columns(&self, n: usize) -> (f64, f64, usize, f64) {
        let n = n as f64;
        (n / self.seconds, self.rays as f64 / self.seconds / 1e6, self.built, self.rays as f64 / n)
    }
}

fn run_pass(
    scene: &Scene,
    bdpt: &Bdpt,
    starts: &[PathState],
    walk: WalkSettings,
    direction: TraceDirection,
) -> Pass {
    let params = HalfVectorParams { walk, direction, ..HalfVectorParams::default() };
    let mut mutation = HalfVectorMutation::new(params);
    let mut ctx = PathContext::new(scene, bdpt);
    // The same stream in every mode: the same targets, so the same walks, differ only in ray casting.
    let mut rng = Sampler::new(0x4853, 0, 0);
    let start = Instant::now();
    let mut built = 0;
    let mut acceptance_sum = 0.0;
    let mut stats = MutationStats::default();
    for x in starts {
        match mutation.propose(x, &mut ctx, &mut rng, &mut stats) {
            Ok(p) => {
                built += 1;
                let ratio = p.state.luminance() * p.t_ratio / x.luminance();
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

/// Up to `count` stationary paths the half-vector mutation applies to, drawn ∝ contribution from a BDPT
/// seeding pass of the scene's film size (at least 16k paths).
pub fn stationary_starts(scene: &Scene, bdpt: &Bdpt, count: usize) -> anyhow::Result<Vec<PathState>> {
    let pixels = scene.film.width * scene.film.height;
    let seeds = PathSeeds::run(scene, bdpt, 1, (4 * pixels).clamp(16_384, 1 << 20), &AtomicBool::new(false));
    if seeds.candidates() == 0 {
        anyhow::bail!("the seeding pass found no light-carrying path");
    }
    let mut rng = Sampler::new(0x5EED, 0, 0);
    let mut starts = Vec::with_capacity(count);
    for _ in 0..count.saturating_mul(200) {
        if starts.len() == count {
            break;
        }
        if let Some(x) = seeds.draw(scene, bdpt, 1, rng.next_f64()) {
            if applicable(&x.vertices) {
                starts.push(x);
            }
        }
    }
    if starts.is_empty() {
        anyhow::bail!("no path of this scene has a glossy inner vertex for the half-vector mutation");
    }
    Ok(starts)
}

/// The forward walk of one HSLT proposal: its start path, index ratios and sampled half-vector targets.
#[derive(Clone, Debug)]
pub struct ProposalWalk {
    pub path: Vec<Vertex>,
    pub eta: Vec<f64>,
    pub target: Vec<DVec2>,
    /// The start path's frame chart, which the mutation's walk holds (`manifold::frame_chart`).
    pub chart: Vec<glam::DVec3>,
}

impl ProposalWalk {
    pub fn job(&self) -> WalkJob<'_> {
        WalkJob {
            path: &self.path,
            eta: &self.eta,
            target: &self.target,
            chart: Some(&self.chart),
            start: None,
        }
    }
}

/// The forward walks the half-vector mutation with `params` would start from `starts` (targets drawn
/// from each path's proposal kernel as `propose` draws them, from a stream seeded by `seed`); paths it
/// cannot prepare or whose kernel is grazing are skipped.
pub fn proposal_walks(
    scene: &Scene,
    starts: &[PathState],
    params: HalfVectorParams,
    seed: u64,
) -> Vec<ProposalWalk> {
    let mutation = HalfVectorMutation::new(params);
    let mut rng = Sampler::new(seed, 0, 0);
    starts
        .iter()
        .filter_map(|x| {
            let prepared = mutation.prepare(scene, &x.vertices, x.film).ok()?;
            let mut target = Vec::with_capacity(prepared.h.len());
            for (step, centre) in prepared.steps.iter().zip(&prepared.h) {
                let u = [rng.next_f64(), rng.next_f64()];
                target.push(step.proposal(*centre)?.sample(u)?);
            }
            Some(ProposalWalk { path: x.vertices.clone(), eta: prepared.eta, target, chart: prepared.chart })
        })
        .collect()
}

/// One timed pass of all walks, `group` in flight at a time; with `fingerprints`, also a hash per walk
/// of its outcome (every bit of the result or the error) and ray count, taken after the clock stops.
fn run_walks(
    scene: &Scene,
    jobs: &[WalkJob],
    group: usize,
    settings: &WalkSettings,
    fingerprints: bool,
) -> (Pass, Vec<u64>) {
    let mut rays = vec![0; jobs.len()];
    let mut results = Vec::with_capacity(jobs.len());
    let start = Instant::now();
    for (chunk, rays) in jobs.chunks(group).zip(rays.chunks_mut(group)) {
        results.extend(walk_many(scene, chunk, settings, rays));
    }
    let seconds = start.elapsed().as_secs_f64();
    let built = results.iter().filter(|r| r.is_ok()).count();
    // Debug prints floats in shortest round-trip form, so equal text means equal bits.
    let hashes = if fingerprints {
        results
            .iter()
            .zip(&rays)
            .map(|(r, n)| {
                let mut hasher = std::collections::hash_map::DefaultHasher::new();
                format!("{r:?} {n}").hash(&mut hasher);
                hasher.finish()
            })
            .collect()
    } else {
        Vec::new()
    };
    (
        Pass {
            seconds,
            rays: rays.iter().sum(),
            built,
            acceptance_sum: 0.0,
            stats: MutationStats::default(),
        },
        hashes,
    )
}

/// Keeps every batch of corrector queries, to replay them against the bare backend.
struct Recorder<'a> {
    inner: &'a dyn RayQuery,
    /// (occlusion query?, rays) per batch call.
    batches: Mutex<Vec<(bool, Vec<Ray>)>>,
}

impl RayQuery for Recorder<'_> {
    fn name(&self) -> &'static str {
        "recorder"
    }
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.inner.intersect(ray)
    }
    fn occluded(&self, ray: &Ray) -> bool {
        self.inner.occluded(ray)
    }
    fn intersect_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        if !rays.is_empty() {
            self.batches.lock().unwrap().push((false, rays.to_vec()));
        }
        self.inner.intersect_batch(rays, hits)
    }
    fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) {
        if !rays.is_empty() {
            self.batches.lock().unwrap().push((true, rays.to_vec()));
        }
        self.inner.occluded_batch(rays, occluded)
    }
}

/// The corrector queries of all walks with `group` in flight, as the batched walk issues them.
fn record_queries(
    scene: &Scene,
    jobs: &[WalkJob],
    group: usize,
    settings: &WalkSettings,
) -> Vec<(bool, Vec<Ray>)> {
    let recorder = Recorder { inner: scene.accel(), batches: Mutex::new(Vec::new()) };
    let mut rays = vec![0; group];
    for chunk in jobs.chunks(group) {
        walk_many_through(scene, &recorder, chunk, settings, &mut rays[..chunk.len()]);
    }
    recorder.batches.into_inner().unwrap()
}

/// Seconds to answer `batches` through the batch API (`batched`) or one ray at a time.
fn replay(accel: &dyn RayQuery, batches: &[(bool, Vec<Ray>)], batched: bool) -> f64 {
    let mut hits = Vec::new();
    let mut occluded = Vec::new();
    let start = Instant::now();
    for (occlusion, rays) in batches {
        match (*occlusion, batched) {
            (false, true) => {
                hits.clear();
                hits.resize(rays.len(), None);
                accel.intersect_batch(rays, &mut hits);
            }
            (true, true) => {
                occluded.clear();
                occluded.resize(rays.len(), false);
                accel.occluded_batch(rays, &mut occluded);
            }
            (false, false) => rays.iter().for_each(|r| {
                std::hint::black_box(accel.intersect(r));
            }),
            (true, false) => rays.iter().for_each(|r| {
                std::hint::black_box(accel.occluded(r));
            }),
        }
        std::hint::black_box((&hits, &occluded));
    }
    start.elapsed().as_secs_f64()
}

fn median_of(passes: &mut [Pass]) -> &Pass {
    passes.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
    &passes[passes.len() / 2]
}

/// Proposes the HSLT mutation once from each of `proposals` stationary paths the mutation applies to,
/// `repeats` times per mode (alternating, on the calling thread), and reports the medians; then walks
/// the same proposals' forward targets with G = 1, 4, 16, 64 walks in flight.
pub fn bench_hslt(
    scene: &Scene,
    proposals: usize,
    repeats: usize,
    direction: TraceDirection,
) -> anyhow::Result<String> {
    let limits = DepthLimits::of_scene(scene);
    let bdpt = Bdpt::new(limits, scene.integrator.hide_emitters);
    let starts = stationary_starts(scene, &bdpt, proposals)?;
    let repeats = repeats.max(1);
    let lazy = HalfVectorParams::default().walk;
    let at_once = WalkSettings { candidates_at_once: true, ..lazy };
    let at_once_single = WalkSettings { batch_rays: false, ..at_once };
    let mut one_by_one = Vec::new();
    let mut batched = Vec::new();
    let mut single = Vec::new();
    for _ in 0..repeats {
        one_by_one.push(run_pass(scene, &bdpt, &starts, lazy, direction));
        batched.push(run_pass(scene, &bdpt, &starts, at_once, direction));
        single.push(run_pass(scene, &bdpt, &starts, at_once_single, direction));
    }
    let (l, b, s) = (median_of(&mut one_by_one), median_of(&mut batched), median_of(&mut single));
    let mut out = String::new();
    let _ = writeln!(
        out,
        "HSLT proposals from {} stationary paths, one thread, median of {repeats}, traced from: {}",
        starts.len(),
        direction.name()
    );
    let _ = writeln!(
        out,
        "{:<36} {:>14} {:>12} {:>10} {:>12}",
        "step candidates / corrector rays", "mutations/s", "Mrays/s", "built", "rays/mut."
    );
    for (name, p) in [
        ("one by one (default)", l),
        ("three per pass, batched", b),
        ("three per pass, one ray at a time", s),
    ] {
        let (per_s, mrays, built, rays) = p.columns(starts.len());
        let _ = writeln!(out, "{name:<36} {per_s:>14.0} {mrays:>12.2} {built:>10} {rays:>12.1}");
    }
    let _ = writeln!(out, "speed-up of batched over single-ray casts: {:.3}x", s.seconds / b.seconds);
    let _ = writeln!(
        out,
        "speed-up of one candidate at a time over three batched per pass: {:.3}x",
        b.seconds / l.seconds
    );
    let n = starts.len() as f64;
    let sum = |what: &str| l.stats.sums.get(what).copied().unwrap_or(0.0);
    let _ = writeln!(
        out,
        "acceptance {:.4}, built {:.4}, mean Newton iterations {:.2}, traced from the light {:.3}",
        l.acceptance_sum / n,
        l.built as f64 / n,
        sum("newton_iterations") / sum("converged_walks").max(1.0),
        sum("traced_from_light") / n
    );
    let mut failures: Vec<_> = l.stats.failed.iter().collect();
    failures.sort_by(|x, y| y.1.cmp(x.1));
    let failures: Vec<String> = failures.iter().map(|(r, c)| format!("{r} {:.4}", **c as f64 / n)).collect();
    let _ = writeln!(out, "failures per proposal: {}", failures.join(", "));
    bench_walks_in_flight(scene, &starts, repeats, &mut out);
    Ok(out)
}

/// Walks in flight (issue #7): the proposals' forward walks, `G` at a time through `walk_many`.
fn bench_walks_in_flight(scene: &Scene, starts: &[PathState], repeats: usize, out: &mut String) {
    let params = HalfVectorParams::default();
    let walks = proposal_walks(scene, starts, params, 0x4853);
    let jobs: Vec<WalkJob> = walks.iter().map(ProposalWalk::job).collect();
    let batched = params.walk;
    let single = WalkSettings { batch_rays: false, ..batched };
    // (label, walks in flight, settings); the first is the single-ray baseline, the second G = 1.
    // G = 64 with single rays separates the cost of interleaving walks from the packets' effect.
    let modes: [(&str, usize, WalkSettings); 6] = [
        ("G=1, one ray at a time", 1, single),
        ("G=1, batched", 1, batched),
        ("G=4, batched", 4, batched),
        ("G=16, batched", 16, batched),
        ("G=64, batched", 64, batched),
        ("G=64, one ray at a time", 64, single),
    ];
    let mut passes: Vec<Vec<Pass>> = modes.iter().map(|_| Vec::new()).collect();
    let mut outcomes: Vec<Vec<u64>> = Vec::new();
    for repeat in 0..repeats {
        for ((_, group, settings), p) in modes.iter().zip(passes.iter_mut()) {
            let (pass, hashes) = run_walks(scene, &jobs, *group, settings, repeat == 0);
            p.push(pass);
            if repeat == 0 {
                outcomes.push(hashes);
            }
        }
    }
    let medians: Vec<&Pass> = passes.iter_mut().map(|p| median_of(p)).collect();
    let _ = writeln!(out);
    let _ = writeln!(
        out,
        "forward walks of {} of these proposals, G walks in flight sharing each corrector query, median of {repeats}",
        jobs.len()
    );
    let _ = writeln!(
        out,
        "{:<24} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "mode", "walks/s", "Mrays/s", "converged", "rays/walk", "vs G=1", "vs single"
    );
    let (single_s, g1_s) = (medians[0].seconds, medians[1].seconds);
    for ((label, _, _), p) in modes.iter().zip(&medians) {
        let (per_s, mrays, built, rays) = p.columns(jobs.len());
        let (vs_g1, vs_single) = (g1_s / p.seconds, single_s / p.seconds);
        let _ = writeln!(
            out,
            "{label:<24} {per_s:>10.0} {mrays:>10.2} {built:>10} {rays:>10.1} {vs_g1:>9.3}x {vs_single:>9.3}x"
        );
    }
    let differing: Vec<usize> =
        outcomes.iter().map(|o| o.iter().zip(&outcomes[1]).filter(|(a, b)| a != b).count()).collect();
    let _ = writeln!(
        out,
        "walks whose result or ray count differs in any bit from G=1 batched, per mode: {differing:?}"
    );
    // The same queries replayed against the bare backend: Embree's own packet gain on these rays,
    // without the walks' arithmetic around it.
    let _ = writeln!(out, "replayed corrector queries, batch API over single rays (median of {repeats}):");
    for group in [1, 64] {
        let queries = record_queries(scene, &jobs, group, &batched);
        let rays: usize = queries.iter().map(|(_, r)| r.len()).sum();
        let (mut packet, mut one) = (Vec::new(), Vec::new());
        for _ in 0..repeats {
            packet.push(replay(scene.accel(), &queries, true));
            one.push(replay(scene.accel(), &queries, false));
        }
        let (packet, one) = (median(&mut packet), median(&mut one));
        let _ = writeln!(
            out,
            "  G={group:<3} {:>7} queries of {:>5.1} rays: batch {:>6.2} Mrays/s, single {:>6.2} Mrays/s, {:.3}x",
            queries.len(),
            rays as f64 / queries.len().max(1) as f64,
            rays as f64 / packet / 1e6,
            rays as f64 / one / 1e6,
            one / packet
        );
    }
}
