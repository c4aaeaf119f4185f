//! Pieces the geometry cases (digest §5, cases 1–8) share: paths drawn ∝ target from a seeding pass,
//! HSLT-only chains and single proposals with their outcome counts, the detailed-balance identities of
//! `tests/hslt_mutation.rs` as a reusable estimate, and path vertices built by casting rays.

use std::sync::atomic::AtomicBool;

use glam::{DMat2, DVec2, Vec3};

use crate::geometry::{offset_origin, Ray};
use crate::integrators::Bdpt;
use crate::manifold::{path_etas, walk, BlockTridiagonal, WalkResult, WalkSettings};
pub use crate::metropolis::mutations::halfvector::relative_mismatch;
use crate::metropolis::mutations::halfvector::{applicable, HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{
    Chain, Failure, Mutation, MutationStats, PathContext, PathSeeds, PathState, TargetFunction,
    WeightedMutation,
};
use crate::path::Vertex;
use crate::render::DepthLimits;
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// The BDPT the scene's integrator settings describe: it seeds the chains and bounds their depth.
pub fn bdpt(scene: &Scene) -> Bdpt {
    let limits = DepthLimits::of_scene(scene);
    Bdpt::new(limits, scene.integrator.hide_emitters)
}

pub fn target(state: &PathState) -> f64 {
    state.luminance()
}

/// Up to `count` paths drawn ∝ target from a seeding pass of `seed_paths` BDPT samples that satisfy
/// `keep` (at most 20 × `count` draws are tried, so a rare kind of path cannot stall a case).
pub fn draw_paths(
    scene: &Scene,
    seed: u64,
    seed_paths: usize,
    count: usize,
    keep: impl Fn(&PathState) -> bool,
) -> Vec<PathState> {
    let bdpt = bdpt(scene);
    let seeds = PathSeeds::run(scene, &bdpt, seed, seed_paths, &AtomicBool::new(false));
    let mut out = Vec::new();
    if seeds.candidates() == 0 {
        return out;
    }
    let mut rng = Sampler::new(seed, 17, 5);
    for _ in 0..20 * count {
        if out.len() >= count {
            break;
        }
        if let Some(x) = seeds.draw(scene, &bdpt, seed, rng.next_f64()) {
            if keep(&x) {
                out.push(x);
            }
        }
    }
    out
}

/// Paths the half-vector mutation applies to.
pub fn hslt_paths(scene: &Scene, seed: u64, seed_paths: usize, count: usize) -> Vec<PathState> {
    draw_paths(scene, seed, seed_paths, count, |x| applicable(&x.vertices))
}

/// What HSLT-only chains did: the mutation's counts and how many recorded states or weights were not
/// finite (must stay 0: no NaN may reach the film).
pub struct ChainRun {
    pub stats: MutationStats,
    pub bad_records: u64,
}

impl ChainRun {
    pub fn applicable(&self) -> u64 {
        self.stats.proposed - self.stats.not_applicable
    }

    /// Accepted proposals among the applicable ones.
    pub fn acceptance(&self) -> f64 {
        self.stats.accepted as f64 / self.applicable().max(1) as f64
    }

    /// Proposals that ended in a converged, reversible walk (accepted or rejected by the test).
    pub fn walk_success(&self) -> f64 {
        let built = self.stats.accepted + self.stats.rejected + self.stats.rejected_zero;
        built as f64 / self.applicable().max(1) as f64
    }

    /// Every proposal is accounted for exactly once.
    pub fn counts_balance(&self) -> bool {
        let s = &self.stats;
        s.proposed
            == s.accepted
                + s.rejected
                + s.rejected_zero
                + s.rejected_invalid
                + s.not_applicable
                + s.failed_total()
    }

    pub fn mean_newton_iterations(&self) -> f64 {
        let s = &self.stats.sums;
        s.get("newton_iterations").unwrap_or(&0.0) / s.get("converged_walks").copied().unwrap_or(0.0).max(1.0)
    }

    pub fn describe(&self) -> String {
        let failures: Vec<String> = self.stats.failed.iter().map(|(k, v)| format!("{k} {v}")).collect();
        format!(
            "{} applicable, acceptance {:.3}, walks built {:.3}, Newton {:.1}, invalid {}, NaN records {}, \
             failures [{}]",
            self.applicable(),
            self.acceptance(),
            self.walk_success(),
            self.mean_newton_iterations(),
            self.stats.rejected_invalid,
            self.bad_records,
            failures.join(", ")
        )
    }
}

/// Runs one HSLT-only chain of `steps` mutations from each start.
pub fn run_hslt_chains(
    scene: &Scene,
    starts: &[PathState],
    steps: usize,
    params: HalfVectorParams,
    seed: u64,
) -> ChainRun {
    let bdpt = bdpt(scene);
    let mut stats = MutationStats::default();
    let mut bad_records = 0u64;
    for (c, start) in starts.iter().enumerate() {
        let mutation = Box::new(HalfVectorMutation::new(params));
        let mut chain = Chain::new(
            start.clone(),
            vec![WeightedMutation { mutation, weight: 1.0 }],
            TargetFunction::Luminance,
            Sampler::new(seed, c as u64, 1),
        );
        let mut ctx = PathContext::new(scene, &bdpt);
        let mut record = |state: &PathState, weight: f64| {
            let finite = weight.is_finite()
                && weight >= 0.0
                && state.contribution.is_finite()
                && state.contribution.min_element() >= 0.0
                && state.film.is_finite();
            bad_records += u64::from(!finite);
        };
        for _ in 0..steps {
            chain.step(&mut ctx, &mut record);
        }
        stats.add(&chain.stats()[0]);
    }
    ChainRun { stats, bad_records }
}

/// The median distance in pixels that one proposal from each start moves the film position, over
/// the proposals that produced a path: a chain whose proposals are all accepted may still be frozen.
pub fn median_film_move(scene: &Scene, starts: &[PathState], params: HalfVectorParams, seed: u64) -> f64 {
    let bdpt = bdpt(scene);
    let mut mutation = HalfVectorMutation::new(params);
    let mut ctx = PathContext::new(scene, &bdpt);
    let mut rng = Sampler::new(seed, 5, 5);
    let mut stats = MutationStats::default();
    let mut moves: Vec<f64> = starts
        .iter()
        .filter_map(|x| {
            let p = mutation.propose(x, &mut ctx, &mut rng, &mut stats).ok()?;
            Some((p.state.film - x.film).length() as f64)
        })
        .collect();
    moves.sort_by(f64::total_cmp);
    moves.get(moves.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The two detailed-balance identities of `tests/hslt_mutation.rs` for single proposals from paths
/// x ∝ target, with R = target(y) T(y→x) / (target(x) T(x→y)) (0 for failures): E[R·1valid] −
/// P(valid) = 0 and E[R·1(R<1)] − P(R>1) = 0. Means and standard errors come from the spread between
/// independent passes (each with its own seeding pass): seed draws repeat heavy paths, so the spread
/// between passes is the honest error.
pub struct Balance {
    pub valid_identity: (f64, f64),
    pub tail_identity: (f64, f64),
    pub proposals: usize,
    pub valid: usize,
    pub non_finite: usize,
    pub stats: MutationStats,
}

impl Balance {
    /// |t| of both identities within `sigmas`.
    pub fn holds(&self, sigmas: f64) -> bool {
        let ok = |(m, se): (f64, f64)| m.abs() <= sigmas * se.max(1e-12);
        ok(self.valid_identity) && ok(self.tail_identity)
    }

    pub fn describe(&self) -> String {
        let (a, sa) = self.valid_identity;
        let (b, sb) = self.tail_identity;
        format!(
            "balance E[R·1valid]−P(valid) = {a:.4} ± {sa:.4}, E[R·1(R<1)]−P(R>1) = {b:.4} ± {sb:.4} over {} \
             proposals ({} valid)",
            self.proposals, self.valid
        )
    }
}

pub fn mean_se(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}

pub fn balance(
    scene: &Scene,
    passes: usize,
    seed_paths: usize,
    draws: usize,
    params: HalfVectorParams,
    seed: u64,
) -> Balance {
    balance_where(scene, passes, seed_paths, draws, params, seed, |_, _| true)
}

/// `balance` restricted to the proposals (x, y) with `keep(x, y)`, which must be symmetric
/// (keep(x, y) = keep(y, x)): both identities hold on any such event, and restricting them to where
/// a suspect term of the ratio matters keeps the other proposals' noise out. `valid` counts the kept
/// valid proposals.
pub fn balance_where(
    scene: &Scene,
    passes: usize,
    seed_paths: usize,
    draws: usize,
    params: HalfVectorParams,
    seed: u64,
    keep: impl Fn(&PathState, &PathState) -> bool,
) -> Balance {
    let bdpt = bdpt(scene);
    let mut valid_means = Vec::new();
    let mut tail_means = Vec::new();
    let mut out = Balance {
        valid_identity: (0.0, 0.0),
        tail_identity: (0.0, 0.0),
        proposals: 0,
        valid: 0,
        non_finite: 0,
        stats: MutationStats::default(),
    };
    for pass in 0..passes as u64 {
        let pass_seed = seed * 1000 + pass;
        let seeds = PathSeeds::run(scene, &bdpt, pass_seed, seed_paths, &AtomicBool::new(false));
        if seeds.candidates() == 0 {
            continue;
        }
        let mut mutation = HalfVectorMutation::new(params);
        let mut ctx = PathContext::new(scene, &bdpt);
        let mut rng = Sampler::new(pass_seed, 3, 9);
        let (mut sum_valid, mut sum_tail, mut n) = (0.0, 0.0, 0usize);
        for _ in 0..draws {
            let Some(x) = seeds.draw(scene, &bdpt, pass_seed, rng.next_f64()) else { continue };
            let r = match mutation.propose(&x, &mut ctx, &mut rng, &mut out.stats) {
                Err(Failure::NotApplicable) => continue,
                Err(Failure::Failed(reason)) => {
                    *out.stats.failed.entry(reason).or_insert(0) += 1;
                    None
                }
                Ok(p) => {
                    let r = target(&p.state) * p.t_ratio / target(&x);
                    if !(r.is_finite() && r >= 0.0) {
                        out.non_finite += 1;
                        None
                    } else {
                        keep(&x, &p.state).then_some(r)
                    }
                }
            };
            n += 1;
            if let Some(r) = r {
                out.valid += 1;
                sum_valid += r - 1.0;
                sum_tail += if r < 1.0 { r } else { 0.0 } - if r > 1.0 { 1.0 } else { 0.0 };
            }
        }
        if n > 0 {
            valid_means.push(sum_valid / n as f64);
            tail_means.push(sum_tail / n as f64);
            out.proposals += n;
        }
    }
    if valid_means.len() >= 2 {
        out.valid_identity = mean_se(&valid_means);
        out.tail_identity = mean_se(&tail_means);
    }
    out
}

/// The `<sensor>` element of a pinhole camera at `origin` looking at `target` (XML triples), with
/// a horizontal field of view in degrees and a film of `film` pixels.
pub fn pinhole_xml(fov: f64, origin: &str, target: &str, up: &str, film: (u32, u32)) -> String {
    format!(
        r#"<sensor type="perspective">
    <float name="fov" value="{fov}" />
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="{up}" /></transform>
    <film type="hdrfilm"><integer name="width" value="{}" /><integer name="height" value="{}" /></film>
  </sensor>"#,
        film.0, film.1
    )
}

/// A fixed path endpoint at `p` with no surface (a pinned position, as the camera and point lights are).
pub fn pinned(scene: &Scene, p: Vec3) -> Vertex {
    Vertex { p, ..Vertex::camera(scene) }
}

/// The surface vertex where the ray from `from` towards `aim` first hits the scene.
pub fn hit_towards(scene: &Scene, from: &Vertex, aim: Vec3) -> Option<Vertex> {
    let dir = (aim - from.p).try_normalize()?;
    let origin = offset_origin(from.p, from.offset(), dir);
    let si = scene.intersect(&Ray::new(origin, dir))?;
    Some(Vertex::surface(scene, &si, Spectrum::ONE))
}

/// Builds x_0 … x_k by casting a ray from each vertex towards the next aim point; `None` if one misses.
pub fn cast_path(scene: &Scene, start: Vertex, aims: &[Vec3], end: Vertex) -> Option<Vec<Vertex>> {
    let mut path = vec![start];
    for &aim in aims {
        let next = hit_towards(scene, path.last()?, aim)?;
        path.push(next);
    }
    path.push(end);
    Some(path)
}

/// A walk to `target` (see `manifold::walk`).
pub fn walk_to(
    scene: &Scene,
    path: &[Vertex],
    target: &[DVec2],
    settings: &WalkSettings,
) -> Result<WalkResult, crate::manifold::WalkError> {
    walk(scene, path, &path_etas(scene, path), target, settings)
}

/// Writes a temporary file that lives until the returned guard is dropped (OBJ meshes of the cases).
pub struct TempFile(pub std::path::PathBuf);

impl TempFile {
    pub fn new(name: &str, contents: &str) -> TempFile {
        let path = std::env::temp_dir().join(format!("hslt-stability-{}-{name}", std::process::id()));
        std::fs::write(&path, contents).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        TempFile(path)
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// J as a dense row-major matrix (endpoint couplings left out).
pub fn dense(j: &BlockTridiagonal) -> Vec<Vec<f64>> {
    let n = j.len();
    let mut m = vec![vec![0.0; 2 * n]; 2 * n];
    let mut put = |row: usize, col: usize, block: DMat2| {
        for r in 0..2 {
            for c in 0..2 {
                m[2 * row + r][2 * col + c] = block.col(c)[r];
            }
        }
    };
    for i in 0..n {
        put(i, i, j.b[i]);
        if i > 0 {
            put(i, i - 1, j.a[i]);
        }
        if i + 1 < n {
            put(i, i + 1, j.c[i]);
        }
    }
    m
}

/// (sign, ln|det|) by Gaussian elimination with partial pivoting: the reference the block LU
/// without pivoting is held against, and a determinant that exists where the block LU refuses.
pub fn pivoted_det(mut m: Vec<Vec<f64>>) -> (f64, f64) {
    let n = m.len();
    let (mut sign, mut ln) = (1.0, 0.0);
    for k in 0..n {
        let pivot = (k..n).max_by(|&a, &b| m[a][k].abs().total_cmp(&m[b][k].abs())).unwrap_or(k);
        if pivot != k {
            m.swap(k, pivot);
            sign = -sign;
        }
        let p = m[k][k];
        if p == 0.0 {
            return (0.0, f64::NEG_INFINITY);
        }
        sign *= p.signum();
        ln += p.abs().ln();
        let (upper, lower) = m.split_at_mut(k + 1);
        let pivot_row = &upper[k];
        for row in lower.iter_mut() {
            let f = row[k] / p;
            for (x, y) in row[k..].iter_mut().zip(&pivot_row[k..]) {
                *x -= f * y;
            }
        }
    }
    (sign, ln)
}

pub fn mul(m: &[Vec<f64>], x: &[f64]) -> Vec<f64> {
    m.iter().map(|row| row.iter().zip(x).map(|(a, b)| a * b).sum()).collect()
}

pub fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}
