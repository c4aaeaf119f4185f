//! Veach's bidirectional mutation (Veach & Guibas 1997, §5.3.1; Veach 1997, §11.4.2; design after
//! Mitsuba 0.6's `mut_bidir`): delete a sub-path of the current path, regrow new vertices from both kept
//! ends by random walks and join them with one connection edge. The transition density sums, for the
//! same kept ends, over every split of the new vertices between the two walks that could have made y.
//! When the emitter end is regenerated, the split with no light-side vertex is an eye walk that hits
//! an emitter itself (no connection edge): without it, paths whose emitter follows a Dirac vertex (a
//! light seen through glass or in a mirror) could never be proposed, since no connection can end there.
//! Dirac emitters (point and spot lights) are regenerated like the others, with the Dirac convention
//! for their position (density = the light's selection probability, as in BDPT); rays cannot hit them,
//! so only splits with a light-side vertex make such paths. (They were once refused, which left the
//! large step unable to make any path of a scene lit by a spot light, and its estimate of b, which
//! counts failed proposals as zero, falling towards zero: fig17 rendered 0.1% of its indirect light.)

use crate::bsdf::{BsdfContext, TransportMode};
use crate::geometry::{Ray, Vec2};
use crate::integrators::{bdpt::sample_light_endpoint, Bdpt};
use crate::metropolis::chain::{Failure, Mutation, MutationStats, Proposal};
use crate::metropolis::path_state::{PathContext, PathState};
use crate::path::walk::{self, WalkLimits};
use crate::path::{visible, PathPdfs, PathView, Vertex, VertexKind};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;

pub struct BidirectionalMutation;

/// Edge counts the mutation may propose: a 1-edge path (the camera sees the emitter) lies outside the
/// integrated space when emitters are hidden. The longest is the seeding pass's own limit: b counts
/// every path BDPT can make, so a shorter cap would leave the longer ones' energy in b with no state
/// to carry it, and a chain started on such a path could never leave it (its reverse move would have
/// zero density). Light trapped in a lossless gem by total internal reflection makes such paths
/// common: on the jewelry scene paths of more than 24 segments carry a tenth of the light seen in the
/// diamond.
pub(super) fn edge_range(bdpt: &Bdpt) -> (usize, usize) {
    // Paths below BDPT's minimum length (the direct pass's, when it runs) are not the chains' to make.
    let k_min = (if bdpt.hide_emitters { 2 } else { 1 }).max(bdpt.min_path_vertices.saturating_sub(1));
    let k_max = bdpt.max_path_vertices().saturating_sub(1);
    (k_min, k_max)
}

fn two_tailed_weight(centre: usize, value: usize) -> f64 {
    0.5f64.powi(value.abs_diff(centre).min(1000) as i32)
}

/// Σ_{j=a..=b} 2^−j (zero when a > b).
fn geometric_sum(a: usize, b: usize) -> f64 {
    if a > b {
        return 0.0;
    }
    2.0 * (0.5f64.powi(a.min(1100) as i32) - 0.5f64.powi((b + 1).min(1100) as i32))
}

/// Σ_{v=lo..=hi} 2^−|v − centre| in closed form: a path of hundreds of edges would otherwise pay a
/// sum over every length at each proposal.
fn two_tailed_total(centre: usize, lo: usize, hi: usize) -> f64 {
    let below = if lo <= centre { geometric_sum(centre.saturating_sub(hi), centre - lo) } else { 0.0 };
    let above = if hi > centre { geometric_sum(lo.saturating_sub(centre).max(1), hi - centre) } else { 0.0 };
    below + above
}

/// P(value) for the two-tailed geometric distribution ∝ 2^−|value − centre| on [lo, hi].
pub(super) fn two_tailed_pmf(centre: usize, lo: usize, hi: usize, value: usize) -> f64 {
    if lo > hi || value < lo || value > hi {
        return 0.0;
    }
    two_tailed_weight(centre, value) / two_tailed_total(centre, lo, hi)
}

pub(super) fn sample_two_tailed(centre: usize, lo: usize, hi: usize, u: f64) -> Option<usize> {
    if lo > hi {
        return None;
    }
    let mut rest = u * two_tailed_total(centre, lo, hi);
    for v in lo..=hi {
        rest -= two_tailed_weight(centre, v);
        if rest < 0.0 {
            return Some(v);
        }
    }
    Some(hi)
}

/// The smallest number of deleted edges: enough to reach the new length, and two when the length is
/// kept (deleting one edge and adding one back would only reconnect the same two vertices).
fn min_deleted(k: usize, k_new: usize) -> usize {
    let lo = (k + 1).saturating_sub(k_new);
    lo.max(if k_new == k { 2 } else { 1 })
}

/// T(x→y) for the path `to` (y) proposed from a path x of `from_edges` edges by keeping `to[..=a]` and
/// replacing `deleted` edges of x after x_a by `added` edges; y's kept suffix starts at `a + added`
/// (empty when that is `to.len()`, the emitter was regenerated): P(k'|k) P(kd|k,k') P(a|k,kd) times the
/// regrowth density Σ_s P(s) p_s(y) (`regrowth_density`).
pub fn transition_density(
    scene: &Scene,
    bdpt: &Bdpt,
    from_edges: usize,
    to: &[Vertex],
    a: usize,
    deleted: usize,
    added: usize,
) -> f64 {
    let (k_min, k_max) = edge_range(bdpt);
    let (k, n) = (from_edges, to.len());
    let c = a + added;
    if n < 2 || added == 0 || deleted == 0 || c > n || n - 1 + deleted != k + added {
        return 0.0;
    }
    if a + deleted > k + 1 {
        return 0.0;
    }
    let k_new = n - 1;
    let p_length = two_tailed_pmf(k, k_min, k_max, k_new);
    let p_deleted = two_tailed_pmf(2, min_deleted(k, k_new), k + 1, deleted);
    let p_position = 1.0 / (k + 2 - deleted) as f64;
    if c == n && deleted == 1 {
        return 0.0;
    }
    p_length * p_deleted * p_position * regrowth_density(scene, to, a, added)
}

/// Σ_s P(s) p_s(y): the density with which `regrow` makes `to` from its kept prefix `to[..=a]` and kept
/// suffix `to[a + added..]` (empty when that is `to.len()`), summed over the uniformly chosen splits s
/// of the new vertices into s light-side and the rest eye-side ones (`split_density`).
pub(super) fn regrowth_density(scene: &Scene, to: &[Vertex], a: usize, added: usize) -> f64 {
    if added == 0 || a + added > to.len() {
        return 0.0;
    }
    split_densities(scene, to, a, added).iter().sum::<f64>() / added as f64
}

/// p_s(y) for every split s = 0 … `added` − 1 of the new vertices (`split_density`), for samplers that
/// choose the split by their own pmf (the large step); empty where nothing was regrown.
pub(super) fn split_densities(scene: &Scene, to: &[Vertex], a: usize, added: usize) -> Vec<f64> {
    if added == 0 || a + added > to.len() {
        return Vec::new();
    }
    let pdfs = PathView::whole(to).dirac_pdfs(scene);
    (0..added).map(|s| split_density(scene, to, &pdfs, a, added, s)).collect()
}

/// p_s(y): the density with which `regrow`, having chosen the split `s`, makes `to`: the product of the
/// Dirac-convention densities (`PathView::dirac_pdfs`, passed in as `pdfs`) of the new vertices from
/// their own side. Zero where `regrow` refuses the ends or the split.
fn split_density(scene: &Scene, to: &[Vertex], pdfs: &PathPdfs, a: usize, added: usize, s: usize) -> f64 {
    let n = to.len();
    let c = a + added;
    let suffix_empty = c == n;
    if to[a].delta || (!suffix_empty && dirac_scatter(scene, &to[c])) || (added < 2 && suffix_empty) {
        return 0.0;
    }
    let kept_environment = !suffix_empty && c == n - 1 && to[n - 1].kind == VertexKind::InfiniteLight;
    if kept_environment && s >= 1 {
        return 0.0;
    }
    let t = added - 1 - s;
    if suffix_empty && s == 0 {
        // The eye walk itself ended on the emitter (no connection edge).
        if !hit_emitter(scene, &to[n - 1]) {
            return 0.0;
        }
        return pdfs.from_camera[a + 1..n].iter().map(|&p| p as f64).product();
    }
    let (eye_end, light_end) = (&to[a + t], &to[a + t + 1]);
    let camera_to_environment =
        eye_end.kind == VertexKind::Camera && light_end.kind == VertexKind::InfiniteLight;
    if !eye_end.connectible() || !light_end.connectible() || camera_to_environment {
        return 0.0;
    }
    let eye: f64 = pdfs.from_camera[a + 1..=a + t].iter().map(|&p| p as f64).product();
    let light: f64 = pdfs.from_light[c - s..c].iter().map(|&p| p as f64).product();
    eye * light
}

/// Whether an eye walk may end on `v` by hitting it: a point on an emitting surface (not a Dirac light,
/// which rays cannot hit, nor an environment, whose choice among several would need its own density).
/// The same point is a `Surface` vertex when an eye walk hit it and a `Light` vertex when it was sampled
/// on the light; the density of a path must not depend on which, or the s = 0 term of paths whose
/// emitter was sampled goes missing from the sum (it did: a 1.5% excess in the large step's estimate).
fn hit_emitter(scene: &Scene, v: &Vertex) -> bool {
    matches!(v.kind, VertexKind::Surface | VertexKind::Light) && v.light.is_some() && !v.is_delta_light(scene)
}

/// Whether a kept vertex scattered through a Dirac lobe. A point or spot light endpoint is flagged
/// `delta` for its Dirac position, not for a lobe: it stays a valid kept end, from which emission
/// directions are sampled with a proper density.
fn dirac_scatter(scene: &Scene, v: &Vertex) -> bool {
    v.delta && !v.is_delta_light(scene)
}

/// Whether two vertices are the same kept vertex (copied, so bit-identical).
fn same_vertex(x: &Vertex, y: &Vertex) -> bool {
    x.kind == y.kind && x.p == y.p
}

/// T(x→y) with the kept prefix and suffix recovered by comparing the paths, for checks from outside:
/// one density per way the mutation could have made y from x. New vertices never coincide with
/// deleted ones except on a set of measure zero, with one exception: a regenerated Dirac emitter (a
/// point or spot light) is the same point as the deleted one. When the paths share only that emitter
/// at their ends, the second entry is the density with the emitter regenerated (empty suffix).
pub fn transition_densities_between(scene: &Scene, bdpt: &Bdpt, x: &[Vertex], y: &[Vertex]) -> Vec<f64> {
    let shorter = x.len().min(y.len());
    let prefix = x.iter().zip(y).take_while(|(u, v)| same_vertex(u, v)).count().min(shorter);
    let suffix = x
        .iter()
        .rev()
        .zip(y.iter().rev())
        .take_while(|(u, v)| same_vertex(u, v))
        .count()
        .min(shorter - prefix);
    let density = |prefix: usize, suffix: usize| {
        if prefix == 0 {
            return 0.0;
        }
        let a = prefix - 1;
        let (deleted, added) = (x.len() - suffix - a, y.len() - suffix - a);
        transition_density(scene, bdpt, x.len() - 1, y, a, deleted, added)
    };
    let mut densities = vec![density(prefix, suffix)];
    let (last_x, last_y) = (&x[x.len() - 1], &y[y.len() - 1]);
    if same_vertex(last_x, last_y) && last_x.is_delta_light(scene) && (suffix == 1 || prefix == shorter) {
        // The shared emitter may have been regenerated: it belongs to neither kept part.
        densities.push(density(prefix.min(shorter - 1), 0));
    }
    densities
}

/// A direction sampled by the BSDF at a kept vertex `v` (with `wi` towards `towards`), as the first
/// ray of a walk. Dirac lobes are refused so kept vertices stay non-Dirac in both directions.
fn kept_vertex_ray(
    scene: &Scene,
    v: &Vertex,
    towards: &Vertex,
    mode: TransportMode,
    rng: &mut Sampler,
) -> Result<Ray, Failure> {
    let bsdf = v.bsdf(scene).ok_or(Failure::Failed("kept_vertex_not_surface"))?;
    let ctx = BsdfContext { mode, uv: v.uv };
    let wi = v.frame.to_local(v.direction_to(towards));
    let u_lobe = rng.next_1d();
    let u = rng.next_2d();
    let bs = bsdf.sample(&ctx, wi, u_lobe, u).ok_or(Failure::Failed("bsdf_sample"))?;
    if bs.lobe.is_delta() {
        return Err(Failure::Failed("dirac_lobe_at_kept_vertex"));
    }
    if !(bs.pdf > 0.0) {
        return Err(Failure::Failed("bsdf_sample"));
    }
    let wo = v.frame.to_world(bs.wo);
    Ok(Ray::leaving(v.p, wo, v.eps))
}

/// Grows `path` by exactly `count` vertices along `ray` without Russian roulette.
fn walk_exactly(
    ctx: &mut PathContext,
    path: &mut Vec<Vertex>,
    ray: Ray,
    mode: TransportMode,
    count: usize,
    rng: &mut Sampler,
) -> Result<(), Failure> {
    let target = path.len() + count;
    let limits = WalkLimits { max_vertices: target, rr_depth: -1 };
    let escaped = walk::extend(ctx.scene, path, ray, Spectrum::ONE, mode, limits, rng, &mut ctx.counters);
    if escaped.is_some() {
        return Err(Failure::Failed("walk_escaped"));
    }
    if path.len() != target {
        return Err(Failure::Failed("walk_absorbed"));
    }
    Ok(())
}

impl<'a> Mutation<PathState, PathContext<'a>> for BidirectionalMutation {
    fn name(&self) -> &'static str {
        "bidir"
    }

    fn propose(
        &mut self,
        current: &PathState,
        ctx: &mut PathContext<'a>,
        rng: &mut Sampler,
        stats: &mut MutationStats,
    ) -> Result<Proposal<PathState>, Failure> {
        let x = &current.vertices;
        if x.len() < 2 {
            return Err(Failure::NotApplicable);
        }
        let k = x.len() - 1;
        let (k_min, k_max) = edge_range(ctx.bdpt);
        let k_new = sample_two_tailed(k, k_min, k_max, rng.next_f64()).ok_or(Failure::NotApplicable)?;
        let deleted = sample_two_tailed(2, min_deleted(k, k_new), k + 1, rng.next_f64())
            .ok_or(Failure::Failed("no_deletion"))?;
        let added = k_new + deleted - k;
        let positions = k + 2 - deleted;
        let a = ((rng.next_f64() * positions as f64) as usize).min(positions - 1);
        let b = a + deleted;
        if b == k + 1 && deleted == 1 {
            return Err(Failure::Failed("emitter_would_be_inner"));
        }
        let y = regrow(ctx, x, a, b, added, rng)?;
        finish(ctx, current, y, (a, deleted, added), stats)
    }
}

/// Replaces the vertices of `x` strictly between x_a and x_b (b = `x.len()`: the emitter too) by
/// `added` new edges, grown from both kept ends by random walks and joined by one connection edge; the
/// split between the two walks is uniform (`regrowth_density` is the density of the result).
pub(super) fn regrow(
    ctx: &mut PathContext,
    x: &[Vertex],
    a: usize,
    b: usize,
    added: usize,
    rng: &mut Sampler,
) -> Result<Vec<Vertex>, Failure> {
    check_kept_ends(ctx.scene, x, a, b, added)?;
    let s = ((rng.next_f64() * added as f64) as usize).min(added - 1);
    grow_split(ctx, x, a, b, added, s, rng)
}

/// Why `x_a` and `x_b` cannot be kept ends of a regrowth of `added` edges, if they cannot.
fn check_kept_ends(scene: &Scene, x: &[Vertex], a: usize, b: usize, added: usize) -> Result<(), Failure> {
    let k = x.len() - 1;
    let suffix_empty = b == k + 1;
    if x[a].delta || (!suffix_empty && dirac_scatter(scene, &x[b])) {
        return Err(Failure::Failed("dirac_kept_vertex"));
    }
    // With the emitter regenerated, s = 0 means the eye walk must hit an emitter itself: the only
    // way to build paths whose light end follows a Dirac vertex (a light seen through glass).
    if added == 0 || (suffix_empty && added < 2) {
        return Err(Failure::Failed("no_split"));
    }
    Ok(())
}

/// `regrow` with the split chosen by the caller (the large step draws it from its own pmf): `s` of the
/// `added` new vertices grown from the light side, the rest from the eye side.
pub(super) fn regrow_split(
    ctx: &mut PathContext,
    x: &[Vertex],
    a: usize,
    b: usize,
    added: usize,
    s: usize,
    rng: &mut Sampler,
) -> Result<Vec<Vertex>, Failure> {
    check_kept_ends(ctx.scene, x, a, b, added)?;
    if s >= added {
        return Err(Failure::Failed("no_split"));
    }
    grow_split(ctx, x, a, b, added, s, rng)
}

/// The regrowth itself, on kept ends and a split already checked (`check_kept_ends`, s < `added`).
fn grow_split(
    ctx: &mut PathContext,
    x: &[Vertex],
    a: usize,
    b: usize,
    added: usize,
    s: usize,
    rng: &mut Sampler,
) -> Result<Vec<Vertex>, Failure> {
    let scene = ctx.scene;
    let k = x.len() - 1;
    let suffix_empty = b == k + 1;
    let t = added - 1 - s;
    if !suffix_empty && b == k && x[k].kind == VertexKind::InfiniteLight && s >= 1 {
        return Err(Failure::Failed("unsupported"));
    }

    let mut eye: Vec<Vertex> = x[..=a].to_vec();
    if t > 0 {
        let ray = if a == 0 {
            let u = rng.next_2d();
            let film = Vec2::new(u.x * scene.film.width as f32, u.y * scene.film.height as f32);
            scene.camera.generate_ray(film)
        } else {
            kept_vertex_ray(scene, &x[a], &x[a - 1], TransportMode::Radiance, rng)?
        };
        walk_exactly(ctx, &mut eye, ray, TransportMode::Radiance, t, rng)?;
    }

    if suffix_empty && s == 0 {
        if !hit_emitter(scene, &eye[eye.len() - 1]) {
            return Err(Failure::Failed("missed_emitter"));
        }
        return Ok(eye);
    }

    // The light side is held from the emitter inwards, as the walk grows it.
    let mut light: Vec<Vertex>;
    if suffix_empty {
        let (u_light, u_pos, u_dir) = (rng.next_1d(), rng.next_2d(), rng.next_2d());
        let start =
            sample_light_endpoint(scene, u_light, u_pos, u_dir).ok_or(Failure::Failed("no_emission"))?;
        light = vec![start.vertex];
        if s > 1 {
            walk_exactly(ctx, &mut light, start.ray, TransportMode::Importance, s - 1, rng)?;
        }
    } else {
        light = x[b..].iter().rev().copied().collect();
        if s > 0 {
            let ray = if b == k {
                let emitter = &x[k];
                let dir = emitter
                    .sample_emission_direction(scene, rng.next_2d())
                    .ok_or(Failure::Failed("no_emission"))?;
                if emitter.is_surface() {
                    Ray::leaving(emitter.p, dir, emitter.eps)
                } else {
                    Ray::new(emitter.p, dir)
                }
            } else {
                kept_vertex_ray(scene, &x[b], &x[b + 1], TransportMode::Importance, rng)?
            };
            walk_exactly(ctx, &mut light, ray, TransportMode::Importance, s, rng)?;
        }
    }

    let (eye_end, light_end) = (&eye[eye.len() - 1], &light[light.len() - 1]);
    let camera_to_environment =
        eye_end.kind == VertexKind::Camera && light_end.kind == VertexKind::InfiniteLight;
    if !eye_end.connectible() || !light_end.connectible() || camera_to_environment {
        return Err(Failure::Failed("not_connectible"));
    }
    ctx.counters.rays += 1;
    ctx.counters.shadow_rays += 1;
    if !visible(scene, eye_end, light_end) {
        return Err(Failure::Failed("occluded"));
    }
    let mut y = eye;
    y.extend(light.iter().rev());
    Ok(y)
}

/// Evaluates the proposed path y and the ratio of the two transition densities.
fn finish(
    ctx: &PathContext,
    current: &PathState,
    y: Vec<Vertex>,
    (a, deleted, added): (usize, usize, usize),
    stats: &mut MutationStats,
) -> Result<Proposal<PathState>, Failure> {
    let (scene, x) = (ctx.scene, &current.vertices);
    let (k, k_new) = (x.len() - 1, x.len() - 1 + added - deleted);
    if y.len() > ctx.max_vertices() || y.len() != k_new + 1 {
        return Err(Failure::Failed("too_long"));
    }
    let state = PathState::new(scene, y).ok_or(Failure::Failed("zero_contribution"))?;
    let forward = transition_density(scene, ctx.bdpt, k, &state.vertices, a, deleted, added);
    let reverse = transition_density(scene, ctx.bdpt, k_new, x, a, added, deleted);
    let t_ratio = reverse / forward;
    if !(forward > 0.0 && forward.is_finite() && reverse.is_finite() && t_ratio.is_finite()) {
        return Err(Failure::Failed("degenerate_density"));
    }
    stats.add_sum("deleted_vertices", (deleted - 1) as f64);
    stats.add_sum("added_vertices", (added - 1) as f64);
    Ok(Proposal { state, t_ratio })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_tailed_lengths_are_normalised_and_sampled_by_their_pmf() {
        for (centre, lo, hi) in
            [(3, 1, 8), (1, 2, 64), (70, 1, 64), (2, 2, 2), (200, 1, 255), (40, 45, 255), (0, 0, 5)]
        {
            let total: f64 = (lo..=hi).map(|v| two_tailed_pmf(centre, lo, hi, v)).sum();
            assert!((total - 1.0).abs() < 1e-12, "({centre}, {lo}, {hi}): sums to {total}");
            assert_eq!(two_tailed_pmf(centre, lo, hi, hi + 1), 0.0);
            // Frequencies of 20 000 draws within 5 binomial standard deviations of the pmf.
            let n = 20_000;
            let mut rng = Sampler::new(1, centre as u64, lo as u64);
            let mut counts = vec![0usize; hi + 1];
            for _ in 0..n {
                counts[sample_two_tailed(centre, lo, hi, rng.next_f64()).unwrap()] += 1;
            }
            for (v, &count) in counts.iter().enumerate().skip(lo) {
                let p = two_tailed_pmf(centre, lo, hi, v);
                let sd = (n as f64 * p * (1.0 - p)).sqrt();
                assert!((count as f64 - n as f64 * p).abs() <= 5.0 * sd + 1.0, "value {v}");
            }
        }
        assert_eq!(sample_two_tailed(2, 3, 1, 0.5), None);
    }

    #[test]
    fn the_closed_form_normaliser_equals_the_sum() {
        for centre in 0..40 {
            for lo in 0..12 {
                for hi in [lo, lo + 1, 20, 39, 255] {
                    if hi < lo {
                        continue;
                    }
                    let direct: f64 = (lo..=hi).map(|v| two_tailed_weight(centre, v)).sum();
                    let closed = two_tailed_total(centre, lo, hi);
                    assert!(
                        (closed - direct).abs() < 1e-12 * direct,
                        "({centre}, {lo}, {hi}): {closed} vs {direct}"
                    );
                }
            }
        }
    }

    #[test]
    fn deletions_never_reconnect_the_same_vertices_and_reach_the_new_length() {
        assert_eq!(min_deleted(4, 4), 2);
        assert_eq!(min_deleted(4, 5), 1);
        assert_eq!(min_deleted(4, 2), 3);
        // k' = 1 from k = 4: four of the five edges (counting the light supernode's) must go.
        assert_eq!(min_deleted(4, 1), 4);
    }
}
