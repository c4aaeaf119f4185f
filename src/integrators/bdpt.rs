//! Bidirectional path tracing (Veach 1997, ch. 10; Lafortune & Willems 1993): a camera sub-path and a
//! light sub-path per sample, every connection (s, t) between them evaluated — including light paths
//! joined to the camera (t = 1, splatted to the film) — and weighted by multiple importance sampling in
//! area measure over all strategies that could have produced the same path. The per-sample work is in
//! `Bdpt::sample`, which Metropolis methods reuse with their own sample source.
//!
//! Parameters (`<integrator type="bdpt">`, or the CLI): `max_depth` (longest path in segments, −1 =
//! unbounded), `rr_depth` (Russian roulette from this many segments), `hide_emitters`.

use crate::bsdf::TransportMode;
use crate::geometry::{Ray, Vec2, Vec3};
use crate::lights::{EmissionSample, Light};
use crate::path::walk::{self, WalkLimits};
use crate::path::{geometry_term, mis_weight_limited, visible, MisHeuristic, PathPdfs, PathView, Vertex};
use crate::render::{DepthLimits, PixelIntegrator, SampleCounters, SampleOutput, Splat};
use crate::sampling::{SampleSource, Sampler};
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// Longest sub-path when `max_depth` is unbounded; Russian roulette ends paths long before.
const UNBOUNDED_VERTICES: usize = 256;

#[derive(Clone, Debug)]
pub struct Bdpt {
    pub limits: DepthLimits,
    pub hide_emitters: bool,
    pub heuristic: MisHeuristic,
    /// Write each strategy's weighted contribution as an extra layer, for path depths up to this.
    pub strategy_layers: Option<u32>,
    /// Shortest full path (in vertices) whose strategies are estimated: 2 estimates everything; the
    /// Metropolis integrators raise it to 4 when direct illumination is rendered separately
    /// (`metropolis::direct`), so the seeding pass and PSSMLT's samples carry indirect light only.
    pub min_path_vertices: usize,
    /// Most vertices of the light sub-path, and so of the light side of every strategy (s ≤ this);
    /// the MIS weights leave out the strategies above it. Unbounded by default; the Metropolis
    /// direct pass sets 1 with `max_depth` 1 for the emitters seen directly: the camera ray that hits
    /// one and the emitter's points joined to the camera (s = 1, t = 1; `metropolis::direct`).
    pub max_light_vertices: usize,
}

/// One weighted strategy estimate of a sample.
#[derive(Clone, Copy, Debug)]
pub struct Contribution {
    /// Light and camera vertex counts of the strategy.
    pub s: usize,
    pub t: usize,
    /// MIS-weighted estimate.
    pub value: Spectrum,
    /// Film position for light-tracing estimates (t = 1); `None` means the camera sample's own position.
    pub film: Option<Vec2>,
    /// The emitter endpoint when it is not on the light sub-path: the light sample of s = 1, or the
    /// environment a camera path escaped to (s = 0). Path-space MLT rebuilds the path with it.
    pub endpoint: Option<Vertex>,
}

impl Contribution {
    /// The full path x_0 … x_k of this strategy on the sub-paths it was made from.
    pub fn path(&self, sub: &Subpaths) -> Vec<Vertex> {
        let mut path: Vec<Vertex> = sub.camera[..self.t.min(sub.camera.len())].to_vec();
        match (self.s, self.endpoint) {
            (0, Some(env)) => path.push(env),
            (1, Some(light)) => path.push(light),
            _ => path.extend(sub.light[..self.s].iter().rev()),
        }
        path
    }
}

/// The sub-paths of one sample, kept so tests can re-evaluate what the integrator computed.
#[derive(Clone, Debug, Default)]
pub struct Subpaths {
    pub camera: Vec<Vertex>,
    pub light: Vec<Vertex>,
    /// Direction and throughput of the camera ray that left the scene, if it did.
    pub escaped: Option<(Vec3, Spectrum)>,
}

impl Bdpt {
    pub fn new(limits: DepthLimits, hide_emitters: bool) -> Bdpt {
        Bdpt {
            limits,
            hide_emitters,
            heuristic: MisHeuristic::Power,
            strategy_layers: None,
            min_path_vertices: 2,
            max_light_vertices: usize::MAX,
        }
    }

    /// Most vertices a full path may have.
    pub fn max_path_vertices(&self) -> usize {
        if self.limits.max_depth < 0 {
            UNBOUNDED_VERTICES
        } else {
            self.limits.max_depth as usize + 1
        }
    }

    /// Traces both sub-paths for a camera ray. Stream 0 drives the camera walk, 1 the light walk.
    pub fn trace_subpaths<S: SampleSource + ?Sized>(
        &self,
        scene: &Scene,
        camera_ray: &Ray,
        sampler: &mut S,
        counters: &mut SampleCounters,
    ) -> Subpaths {
        let max_vertices = self.max_path_vertices();
        let rr_depth = self.limits.rr_depth;
        let mut sub = Subpaths::default();
        sampler.start_stream(0);
        sub.camera.push(Vertex::camera(scene));
        sub.escaped = walk::extend(
            scene,
            &mut sub.camera,
            *camera_ray,
            Spectrum::ONE,
            TransportMode::Radiance,
            WalkLimits { max_vertices, rr_depth },
            sampler,
            counters,
        );

        sampler.start_stream(1);
        // A light path of s vertices only pairs with t >= 1 camera vertices, so it needs at most
        // max_vertices - 1 of them.
        let light_max = (max_vertices - 1).min(self.max_light_vertices);
        let u_light = sampler.next_1d();
        let u_pos = sampler.next_2d();
        let u_dir = sampler.next_2d();
        if light_max == 0 {
            return sub;
        }
        let Some(start) = sample_light_endpoint(scene, u_light, u_pos, u_dir) else { return sub };
        sub.light.push(start.vertex);
        if start.beta.is_finite() && start.beta.max_element() > 0.0 {
            walk::extend(
                scene,
                &mut sub.light,
                start.ray,
                start.beta,
                TransportMode::Importance,
                WalkLimits { max_vertices: light_max, rr_depth },
                sampler,
                counters,
            );
        }
        sub
    }

    /// All weighted strategy estimates of one sample. Stream 2 drives light sampling for s = 1.
    pub fn sample<S: SampleSource + ?Sized>(
        &self,
        scene: &Scene,
        camera_ray: &Ray,
        sampler: &mut S,
        counters: &mut SampleCounters,
        out: &mut Vec<Contribution>,
    ) -> Subpaths {
        let sub = self.trace_subpaths(scene, camera_ray, sampler, counters);
        sampler.start_stream(2);
        let max_vertices = self.max_path_vertices();
        for t in 1..=sub.camera.len() {
            for s in 0..=sub.light.len() {
                let n = s + t;
                if n < self.min_path_vertices.max(2) || n > max_vertices || (self.hide_emitters && n == 2) {
                    continue;
                }
                if let Some(c) = self.connect(scene, &sub, s, t, sampler, counters) {
                    out.push(c);
                }
            }
        }
        // Camera rays that left the scene meet each environment light (s = 0).
        if let Some((dir, beta)) = sub.escaped {
            let t = sub.camera.len() + 1;
            if t >= self.min_path_vertices && t <= max_vertices && !(self.hide_emitters && t == 2) {
                for &li in &scene.infinite_lights {
                    let mut camera = sub.camera.clone();
                    let last = camera[camera.len() - 1];
                    let mut env = Vertex::infinite(scene, li, last.p, dir);
                    env.beta = beta;
                    let prev = (camera.len() >= 2).then(|| camera[camera.len() - 2]);
                    env.pdf_from_camera =
                        PathView::density(scene, prev.as_ref(), &last, &env, TransportMode::Radiance);
                    camera.push(env);
                    walk::update_reverse_density(scene, &mut camera, TransportMode::Radiance);
                    let with_env = Subpaths { camera, light: Vec::new(), escaped: None };
                    if let Some(mut c) = self.connect(scene, &with_env, 0, t, sampler, counters) {
                        c.endpoint = Some(with_env.camera[t - 1]);
                        out.push(c);
                    }
                }
            }
        }
        sub
    }

    /// Strategy (s, t) on the sub-paths: its weighted estimate, or `None` if it contributes nothing.
    fn connect<S: SampleSource + ?Sized>(
        &self,
        scene: &Scene,
        sub: &Subpaths,
        s: usize,
        t: usize,
        sampler: &mut S,
        counters: &mut SampleCounters,
    ) -> Option<Contribution> {
        let z = &sub.camera[t - 1];
        let mut sampled_light = None;
        let mut film = None;
        let value = if s == 0 {
            // The camera path itself ends on an emitter.
            z.light?;
            let prev = &sub.camera[t - 2];
            z.beta * z.emitted(scene, z.direction_to(prev))
        } else if t == 1 {
            let y = &sub.light[s - 1];
            if !y.connectible() || y.kind == crate::path::VertexKind::InfiniteLight {
                return None;
            }
            let dir = z.direction_to(y);
            film = Some(scene.camera.film_position(dir)?);
            let scatter = if s == 1 {
                y.emitted(scene, y.direction_to(z))
            } else {
                y.scatter_factor(scene, y.direction_to(z), y.direction_to(&sub.light[s - 2]))
            };
            let v = y.beta * scatter * (scene.camera.importance(dir) * geometry_term(z, y));
            if v == Spectrum::ZERO {
                return None;
            }
            counters.rays += 1;
            counters.shadow_rays += 1;
            if !visible(scene, z, y) {
                return None;
            }
            v
        } else if s == 1 {
            if !z.connectible() {
                return None;
            }
            let y = sample_light_vertex(scene, z.p, sampler)?;
            let prev = &sub.camera[t - 2];
            let v = z.beta
                * z.scatter_factor(scene, z.direction_to(prev), z.direction_to(&y))
                * geometry_term(z, &y)
                * y.emitted(scene, y.direction_to(z))
                * y.beta;
            if v == Spectrum::ZERO {
                return None;
            }
            counters.rays += 1;
            counters.shadow_rays += 1;
            if !visible(scene, z, &y) {
                return None;
            }
            sampled_light = Some(y);
            v
        } else {
            let y = &sub.light[s - 1];
            if !z.connectible() || !y.connectible() {
                return None;
            }
            let v = z.beta
                * z.scatter_factor(scene, z.direction_to(&sub.camera[t - 2]), z.direction_to(y))
                * geometry_term(z, y)
                * y.scatter_factor(scene, y.direction_to(z), y.direction_to(&sub.light[s - 2]))
                * y.beta;
            if v == Spectrum::ZERO {
                return None;
            }
            counters.rays += 1;
            counters.shadow_rays += 1;
            if !visible(scene, z, y) {
                return None;
            }
            v
        };
        if value == Spectrum::ZERO || !value.is_finite() {
            return None;
        }
        let light_side: &[Vertex] = match &sampled_light {
            Some(y) => std::slice::from_ref(y),
            None => &sub.light[..s],
        };
        let path = PathView { camera: &sub.camera[..t], light: light_side };
        let pdfs = connection_pdfs(scene, &path, t);
        let w = mis_weight_limited(scene, &path, &pdfs, t, self.heuristic, self.max_light_vertices);
        Some(Contribution { s, t, value: value * w, film, endpoint: sampled_light })
    }

    /// The layer names for per-strategy images: `d{depth}_s{s}_t{t}` for every strategy up to the
    /// configured depth.
    pub fn strategy_layer_names(&self) -> Vec<String> {
        let Some(max) = self.strategy_layers else { return Vec::new() };
        let mut names = Vec::new();
        for depth in 1..=max as usize {
            for t in 1..=depth + 1 {
                let s = depth + 1 - t;
                names.push(format!("d{depth}_s{s}_t{t}"));
            }
        }
        names
    }

    fn layer_of(&self, c: &Contribution) -> Option<u16> {
        let max = self.strategy_layers? as usize;
        let depth = c.s + c.t - 1;
        if depth == 0 || depth > max {
            return None;
        }
        // Layers are ordered by depth, then by t = 1 ..= depth + 1.
        let before: usize = (1..depth).map(|d| d + 1).sum();
        Some((before + c.t - 1) as u16)
    }
}

/// Densities of a connected path: stored ones for the sub-path interiors, recomputed near the
/// connection edge (x_{t−1}, x_t), where the sub-paths' own walks could not know their neighbours.
pub fn connection_pdfs(scene: &Scene, path: &PathView, t: usize) -> PathPdfs {
    let n = path.len();
    let mut pdfs = PathPdfs {
        from_camera: (0..n).map(|i| path.get(i).pdf_from_camera).collect(),
        from_light: (0..n).map(|i| path.get(i).pdf_from_light).collect(),
    };
    let at = |i: usize| path.get(i);
    let before = |i: usize| (i >= 1).then(|| path.get(i - 1));
    let after = |i: usize| (i + 1 < n).then(|| path.get(i + 1));
    if t < n {
        // x_t sampled from the camera side, and x_{t+1} through it.
        pdfs.from_camera[t] =
            PathView::density(scene, before(t - 1), at(t - 1), at(t), TransportMode::Radiance);
        if t + 1 < n {
            pdfs.from_camera[t + 1] =
                PathView::density(scene, Some(at(t - 1)), at(t), at(t + 1), TransportMode::Radiance);
        }
        pdfs.from_light[t - 1] =
            PathView::density(scene, after(t), at(t), at(t - 1), TransportMode::Importance);
    } else {
        pdfs.from_light[n - 1] = at(n - 1).pdf_light_origin(scene);
    }
    if t >= 2 {
        pdfs.from_light[t - 2] =
            PathView::density(scene, after(t - 1), at(t - 1), at(t - 2), TransportMode::Importance);
    }
    pdfs
}

/// The start of a light sub-path: the emitter endpoint, the emitted ray leaving it and the ray's
/// throughput (emission · cos / density).
#[derive(Clone, Copy, Debug)]
pub struct LightEndpoint {
    pub vertex: Vertex,
    pub ray: Ray,
    pub beta: Spectrum,
}

/// Samples the emitter endpoint of a light sub-path from three uniform draws (light choice, position,
/// direction), as BDPT's light walk starts; path-space MLT's bidirectional mutation regenerates
/// emitters with it so its densities are BDPT's.
pub fn sample_light_endpoint(scene: &Scene, u_light: f32, u_pos: Vec2, u_dir: Vec2) -> Option<LightEndpoint> {
    let (li, pmf, _) = scene.light_selector.sample(u_light)?;
    let light = &scene.lights[li];
    let es = light.sample_le(u_pos, u_dir, scene.bounds.center(), scene.radius())?;
    let pdf_emit = pmf * es.pdf_pos * es.pdf_dir;
    // Emission is evaluated at connection time, so the endpoint's own throughput is 1 / density.
    let mut vertex = Vertex::light(scene, li, &es, Spectrum::splat(1.0 / (pmf * es.pdf_pos)), 0.0);
    // For environment lights the direction is the endpoint's coordinate (its density the origin's)
    // and the disk point belongs to the first hit's density; `pdf_light_origin` knows both cases.
    vertex.pdf_from_light = vertex.pdf_light_origin(scene);
    let cos = if es.ng == Vec3::ZERO { 1.0 } else { es.ng.dot(es.dir).abs() };
    let beta = es.le * (cos / pdf_emit);
    let ray =
        if vertex.is_surface() { Ray::leaving(es.p, es.dir, vertex.eps) } else { Ray::new(es.p, es.dir) };
    Some(LightEndpoint { vertex, ray, beta })
}

/// A light endpoint for next-event connections (s = 1), with β = 1 / (its density).
fn sample_light_vertex<S: SampleSource + ?Sized>(
    scene: &Scene,
    reference: Vec3,
    sampler: &mut S,
) -> Option<Vertex> {
    let u_light = sampler.next_1d();
    let u = sampler.next_2d();
    let (li, pmf, _) = scene.light_selector.sample(u_light)?;
    let light = &scene.lights[li];
    let es = match light {
        Light::Area(a) => {
            let sp = a.sample_point(u);
            EmissionSample {
                p: sp.p,
                ng: sp.ng,
                dir: Vec3::ZERO,
                le: Spectrum::ZERO,
                pdf_pos: a.pdf_area(),
                pdf_dir: 0.0,
                surface: Some(sp),
            }
        }
        Light::Point(_) | Light::Spot(_) => {
            let ls = light.sample_li(reference, u, scene.radius())?;
            EmissionSample {
                p: ls.p,
                ng: Vec3::ZERO,
                dir: Vec3::ZERO,
                le: Spectrum::ZERO,
                pdf_pos: 1.0,
                pdf_dir: 0.0,
                surface: None,
            }
        }
        Light::Constant { .. } | Light::Env(_) => {
            let ls = light.sample_li(reference, u, scene.radius())?;
            EmissionSample {
                p: reference + ls.wi * 2.0 * scene.radius(),
                ng: Vec3::ZERO,
                dir: -ls.wi,
                le: Spectrum::ZERO,
                pdf_pos: ls.pdf,
                pdf_dir: 0.0,
                surface: None,
            }
        }
    };
    let pdf = pmf * es.pdf_pos;
    if !(pdf > 0.0) || !pdf.is_finite() {
        return None;
    }
    Some(Vertex::light(scene, li, &es, Spectrum::splat(1.0 / pdf), pdf))
}

impl PixelIntegrator for Bdpt {
    fn name(&self) -> &'static str {
        "bdpt"
    }

    fn splats(&self) -> bool {
        true
    }

    fn layers(&self) -> Vec<String> {
        self.strategy_layer_names()
    }

    fn li(&self, scene: &Scene, ray: &Ray, sampler: &mut Sampler, out: &mut SampleOutput) -> Spectrum {
        let mut contributions = Vec::new();
        self.sample(scene, ray, sampler, &mut out.counters, &mut contributions);
        let mut radiance = Spectrum::ZERO;
        for c in &contributions {
            let layer = self.layer_of(c);
            match c.film {
                None => {
                    radiance += c.value;
                    if let Some(l) = layer {
                        out.layer_values.push((l, c.value));
                    }
                }
                Some(pos) => {
                    out.splats.push(Splat { pos, value: c.value, layer: None });
                    if let Some(l) = layer {
                        out.splats.push(Splat { pos, value: c.value, layer: Some(l) });
                    }
                }
            }
        }
        radiance
    }
}
