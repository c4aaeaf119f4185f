//! The half-vector plots of the HSLT supplement (Kaplanyan et al. 2014, supplement Sec. 2–3, Fig. 4):
//! sweep one inner vertex's projected half vector h⊥ over the unit disk with both endpoints and every
//! other half vector fixed, and compare f_H = f_A / |det J| (method digest 2.4) with the local BSDF.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::blocktri::BlockLu;
use super::constraint::{path_constraints, path_etas, path_geometry, ConstraintError};
use super::walk::{walk, WalkSettings};
use crate::geometry::Vec2;
use crate::integrators::bdpt::{Bdpt, Subpaths};
use crate::path::{visible, PathView, Vertex, VertexKind};
use crate::render::{DepthLimits, SampleCounters};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::luminance;

/// Where and how to look for a path to plot.
#[derive(Clone, Copy, Debug)]
pub struct PathSearch {
    /// Pixel (column, row) the path's first segment passes through.
    pub pixel: (u32, u32),
    /// Path index of the vertex whose half vector is swept (x_0 is the camera).
    pub vertex: usize,
    /// Longest path, in vertices, endpoints included.
    pub max_vertices: usize,
    pub seed: u64,
    /// Camera samples tried before giving up.
    pub attempts: usize,
}

/// Why no plot can be made.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SweepError {
    #[error("pixel ({x}, {y}) is outside the {width}x{height} image (expected 0 <= X < {width}, 0 <= Y < {height})")]
    PixelOutOfRange { x: u32, y: u32, width: usize, height: usize },
    #[error(
        "vertex index {vertex} is out of range: expected an inner vertex 1 <= I <= {max_inner} (x_0 is the \
         camera, and paths have at most {max_vertices} vertices)"
    )]
    VertexOutOfRange { vertex: usize, max_inner: usize, max_vertices: usize },
    #[error(
        "no path through pixel ({x}, {y}) has a glossy or diffuse vertex {vertex} and reaches an emitter \
         (tried {attempts} camera samples; paths with specular vertices are skipped)"
    )]
    NoPath { x: u32, y: u32, vertex: usize, attempts: usize },
    #[error("the path has {len} vertices: vertex {vertex} is not an inner vertex")]
    NotInner { vertex: usize, len: usize },
    #[error("the path's constraints cannot be evaluated: {0}")]
    Constraint(#[from] ConstraintError),
    #[error("the path's constraint Jacobian is singular at block row {row}")]
    Singular { row: usize },
    #[error("the path contributes nothing (zero f_A, an occluded segment or a Dirac vertex)")]
    ZeroContribution,
}

/// The two plotted quantities on one path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfVectorMeasurement {
    /// f_H = f_A · V / |det J| (luminance), J the constraint Jacobian of the inner vertices.
    pub contribution: f64,
    /// The local BSDF at the swept vertex in the same (projected half-vector) measure:
    /// f_s(ωi, ωo) |n·ωo| |dωo/dω_H| / |n·H|, which for a microfacet BSDF is F G D(H) (H·ωi) / (|n·ωi| |n·H|).
    pub bsdf: f64,
}

/// One evaluated grid point: the converged path and its measurement.
#[derive(Clone, Debug)]
pub struct SweepPoint {
    pub path: Vec<Vertex>,
    pub h: DVec2,
    pub measurement: HalfVectorMeasurement,
}

/// The plots' data: row-major `resolution²` cells over [−1, 1]², row 0 at h⊥.y = +1.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepResult {
    pub resolution: usize,
    pub contribution: Vec<f64>,
    pub bsdf: Vec<f64>,
    /// Inside the disk, the walk converged and every segment is unoccluded.
    pub valid: Vec<bool>,
}

/// The centre of grid cell (column, row) as a projected half vector, or `None` outside the unit disk.
pub fn grid_half_vector(resolution: usize, column: usize, row: usize) -> Option<DVec2> {
    let coord = |i: usize| (i as f64 + 0.5) / resolution as f64 * 2.0 - 1.0;
    let h = DVec2::new(coord(column), -coord(row));
    (h.length_squared() <= 1.0).then_some(h)
}

impl SweepResult {
    /// Each map normalised to a maximum of 1 over the valid cells, then |contribution − bsdf|; zero at
    /// invalid cells.
    pub fn normalised(&self) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let normalise = |values: &[f64]| {
            let max =
                values.iter().zip(&self.valid).filter(|(_, &ok)| ok).map(|(v, _)| *v).fold(0.0, f64::max);
            let scale = if max > 0.0 { 1.0 / max } else { 0.0 };
            values
                .iter()
                .zip(&self.valid)
                .map(|(v, &ok)| if ok { v * scale } else { 0.0 })
                .collect::<Vec<_>>()
        };
        let (c, b) = (normalise(&self.contribution), normalise(&self.bsdf));
        let d = c.iter().zip(&b).map(|(x, y)| (x - y).abs()).collect();
        (c, b, d)
    }

    /// The valid cell with the largest contribution, as its half vector.
    pub fn contribution_peak(&self) -> Option<DVec2> {
        let best = (0..self.contribution.len())
            .filter(|&i| self.valid[i])
            .max_by(|&a, &b| self.contribution[a].total_cmp(&self.contribution[b]))?;
        grid_half_vector(self.resolution, best % self.resolution, best / self.resolution)
    }
}

/// Traces camera sub-paths through `search.pixel` until one, cut after some vertex and ended on an
/// emitter it hit or joined to its light sub-path's emitter endpoint, has `search.vertex` as a glossy or
/// diffuse inner vertex, no Dirac vertex, no occluded segment and a non-zero, non-singular f_H.
pub fn find_path(scene: &Scene, search: &PathSearch) -> Result<Vec<Vertex>, SweepError> {
    let (x, y) = search.pixel;
    let (width, height) = (scene.film.width, scene.film.height);
    if x as usize >= width || y as usize >= height {
        return Err(SweepError::PixelOutOfRange { x, y, width, height });
    }
    let max_vertices = search.max_vertices.max(3);
    if search.vertex == 0 || search.vertex + 2 > max_vertices {
        return Err(SweepError::VertexOutOfRange {
            vertex: search.vertex,
            max_inner: max_vertices - 2,
            max_vertices,
        });
    }
    // No Russian roulette: the walk should reach the requested depth whenever the scene allows it.
    let bdpt = Bdpt::new(DepthLimits { max_depth: max_vertices as i32 - 1, rr_depth: -1 }, false);
    let pixel_index = y as u64 * width as u64 + x as u64;
    let mut counters = SampleCounters::default();
    for attempt in 0..search.attempts {
        let mut sampler = Sampler::new(search.seed, pixel_index, attempt as u64);
        let jitter = sampler.next_2d();
        let ray = scene.camera.generate_ray(Vec2::new(x as f32, y as f32) + jitter);
        let sub = bdpt.trace_subpaths(scene, &ray, &mut sampler, &mut counters);
        let found = candidate_paths(&sub, search.vertex).find(|p| usable(scene, p, search.vertex));
        if let Some(path) = found {
            return Ok(path);
        }
    }
    Err(SweepError::NoPath { x, y, vertex: search.vertex, attempts: search.attempts })
}

/// Full paths with `vertex` inside, shortest first: camera prefixes ending on an emitter they hit
/// (s = 0), and camera prefixes joined to the light sub-path's endpoint (s = 1).
fn candidate_paths(sub: &Subpaths, vertex: usize) -> impl Iterator<Item = Vec<Vertex>> + '_ {
    let light_end = sub.light.first().filter(|l| l.kind != VertexKind::InfiniteLight);
    (vertex + 1..=sub.camera.len()).flat_map(move |t| {
        let hit = (t > vertex + 1 && sub.camera[t - 1].light.is_some()).then(|| sub.camera[..t].to_vec());
        let joined = light_end.map(|l| {
            let mut p = sub.camera[..t].to_vec();
            p.push(*l);
            p
        });
        hit.into_iter().chain(joined)
    })
}

fn usable(scene: &Scene, path: &[Vertex], vertex: usize) -> bool {
    let inner_ok =
        path[1..path.len() - 1].iter().all(|v| v.kind == VertexKind::Surface && v.smooth && !v.delta);
    inner_ok
        && vertex < path.len() - 1
        && measure(scene, path, &path_etas(scene, path), vertex).is_ok_and(|m| m.contribution > 0.0)
}

/// f_H and the local BSDF of `path` at inner vertex `vertex`, without moving anything. `eta` as from
/// `path_etas`.
pub fn measure(
    scene: &Scene,
    path: &[Vertex],
    eta: &[f64],
    vertex: usize,
) -> Result<HalfVectorMeasurement, SweepError> {
    if vertex == 0 || vertex + 1 >= path.len() {
        return Err(SweepError::NotInner { vertex, len: path.len() });
    }
    let constraints = path_constraints(&path_geometry(path), eta)?;
    let lu: BlockLu = constraints.jacobian.factor().map_err(|s| SweepError::Singular { row: s.row })?;
    let f_a = luminance(PathView::whole(path).contribution(scene)) as f64;
    if !(f_a > 0.0) || path.windows(2).any(|s| !visible(scene, &s[0], &s[1])) {
        return Err(SweepError::ZeroContribution);
    }
    // Divide in log space: det J has units of length^-2(k-1) and leaves f64 range on long paths.
    let contribution = (f_a.ln() - lu.log_det().ln_abs).exp();
    Ok(HalfVectorMeasurement { contribution, bsdf: local_bsdf(scene, path, eta[vertex], vertex) })
}

/// f_s(ωi, ωo) |n·ωo| |dωo/dω_H| / |n·H| at `path[vertex]`, with ωi towards the camera side and H the
/// generalised half vector H~ = ωi + η ωo of the constraint (digest 2.1 and 2.4).
fn local_bsdf(scene: &Scene, path: &[Vertex], eta: f64, vertex: usize) -> f64 {
    let v = &path[vertex];
    let to_camera = v.direction_to(&path[vertex - 1]);
    let to_light = v.direction_to(&path[vertex + 1]);
    // scatter_factor is f_s |n_s·ωo| / |n_g·ωo|; the geometric cosine belongs to this term here.
    let rho =
        luminance(v.scatter_factor(scene, to_camera, to_light)) as f64 * v.ng.dot(to_light).abs() as f64;
    let (wi, wo, ng, n) = (to_camera.as_dvec3(), to_light.as_dvec3(), v.ng.as_dvec3(), v.frame.n.as_dvec3());
    let (cos_i, cos_o) = (ng.dot(wi), ng.dot(wo));
    let eta_rel = if cos_i * cos_o > 0.0 {
        1.0
    } else if cos_i > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    let h_raw: DVec3 = wi + wo * eta_rel;
    let Some(h) = h_raw.try_normalize() else { return 0.0 };
    // Walter et al. 2007: dωo/dω_H = |H~|² / (η² |ωo·H|) (4 |ωo·H| for reflection).
    let jacobian = h_raw.length_squared() / (eta_rel * eta_rel * wo.dot(h).abs());
    let value = rho * jacobian / n.dot(h).abs();
    if value.is_finite() {
        value
    } else {
        0.0
    }
}

/// A path prepared for sweeping one vertex's half vector.
#[derive(Clone)]
pub struct HalfVectorSweep<'a> {
    scene: &'a Scene,
    path: Vec<Vertex>,
    vertex: usize,
    eta: Vec<f64>,
    targets: Vec<DVec2>,
    pub settings: WalkSettings,
}

impl<'a> HalfVectorSweep<'a> {
    /// Checks that `vertex` is an inner vertex of `path` and that the path's constraints evaluate.
    pub fn new(scene: &'a Scene, path: &[Vertex], vertex: usize) -> Result<HalfVectorSweep<'a>, SweepError> {
        if vertex == 0 || vertex + 1 >= path.len() {
            return Err(SweepError::NotInner { vertex, len: path.len() });
        }
        let eta = path_etas(scene, path);
        let targets = path_constraints(&path_geometry(path), &eta)?.h;
        Ok(HalfVectorSweep {
            scene,
            path: path.to_vec(),
            vertex,
            eta,
            targets,
            settings: WalkSettings::default(),
        })
    }

    /// The original path's half vectors h_1 … h_{k−1}.
    pub fn half_vectors(&self) -> &[DVec2] {
        &self.targets
    }

    pub fn path(&self) -> &[Vertex] {
        &self.path
    }

    /// The measurement of the original path.
    pub fn measure_original(&self) -> Result<HalfVectorMeasurement, SweepError> {
        measure(self.scene, &self.path, &self.eta, self.vertex)
    }

    /// Walks from `start` (a path of the same shapes and endpoints) until the swept vertex's half vector
    /// is `h` and the others are the original path's; `None` if the walk fails or f_H is zero there.
    pub fn evaluate_from(&self, start: &[Vertex], h: DVec2) -> Option<SweepPoint> {
        let mut targets = self.targets.clone();
        targets[self.vertex - 1] = h;
        let result = walk(self.scene, start, &self.eta, &targets, &self.settings).ok()?;
        let measurement = measure(self.scene, &result.path, &self.eta, self.vertex).ok()?;
        Some(SweepPoint { path: result.path, h: result.h[self.vertex - 1], measurement })
    }

    /// `evaluate_from` the original path.
    pub fn evaluate(&self, h: DVec2) -> Option<SweepPoint> {
        self.evaluate_from(&self.path, h)
    }

    /// The whole `resolution²` grid. Rows run in parallel; along a row each walk starts from the last
    /// converged neighbour (a short, well-conditioned step) and falls back to the original path.
    pub fn sweep(&self, resolution: usize) -> SweepResult {
        let cell_width = 2.0 / resolution.max(1) as f64;
        // Both maps are evaluated on the same converged path, so an inexact walk only misplaces a cell by
        // its residual; meshes with per-triangle tangent frames leave residuals of ~1e-4 in h (digest 2.8).
        let this = HalfVectorSweep {
            settings: WalkSettings {
                tolerance: (0.05 * cell_width).min(1e-3),
                relative_tolerance: 1.0,
                ..self.settings
            },
            ..self.clone()
        };
        this.sweep_with_settings(resolution)
    }

    fn sweep_with_settings(&self, resolution: usize) -> SweepResult {
        let rows: Vec<Vec<Option<HalfVectorMeasurement>>> = (0..resolution)
            .into_par_iter()
            .map(|row| {
                let mut neighbour: Option<Vec<Vertex>> = None;
                (0..resolution)
                    .map(|column| {
                        let Some(h) = grid_half_vector(resolution, column, row) else {
                            neighbour = None;
                            return None;
                        };
                        let point = neighbour
                            .as_deref()
                            .and_then(|start| self.evaluate_from(start, h))
                            .or_else(|| self.evaluate(h));
                        neighbour = point.as_ref().map(|p| p.path.clone());
                        point.map(|p| p.measurement)
                    })
                    .collect()
            })
            .collect();
        let cells: Vec<Option<HalfVectorMeasurement>> = rows.into_iter().flatten().collect();
        SweepResult {
            resolution,
            contribution: cells.iter().map(|c| c.map_or(0.0, |m| m.contribution)).collect(),
            bsdf: cells.iter().map(|c| c.map_or(0.0, |m| m.bsdf)).collect(),
            valid: cells.iter().map(Option::is_some).collect(),
        }
    }
}

/// Sweeps `path[vertex]`'s half vector over a `resolution²` grid on the unit disk (see `HalfVectorSweep`).
pub fn sweep_half_vector(
    scene: &Scene,
    path: &[Vertex],
    vertex: usize,
    resolution: usize,
) -> Result<SweepResult, SweepError> {
    Ok(HalfVectorSweep::new(scene, path, vertex)?.sweep(resolution))
}
