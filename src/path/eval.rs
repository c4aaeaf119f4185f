//! Evaluation on a whole path: the measurement contribution f(X) in product area measure (Veach 1997,
//! eq. 8.7), the area densities of every vertex from both sides, the density of any (s, t) strategy,
//! and the multiple-importance weight of a strategy among all that could have made the path (§10.2).
//! Everything works on a path given as vertices, so mutations can change a few and re-evaluate.

use super::{geometry_term, Vertex, VertexKind};
use crate::bsdf::TransportMode;
use crate::geometry::Vec2;
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// A full path x_0 … x_{n−1} seen through two slices: vertices traced from the camera (x_0 first) and
/// vertices traced from the light (the emitter first), so BDPT can evaluate a connection without
/// copying its sub-paths. A stored path is a view with an empty light slice.
#[derive(Clone, Copy, Debug)]
pub struct PathView<'a> {
    pub camera: &'a [Vertex],
    pub light: &'a [Vertex],
}

/// MIS heuristic between strategies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MisHeuristic {
    Balance,
    /// Exponent 2 (Veach 1997, §9.2.4).
    Power,
}

/// Area densities of each vertex from both sides, with which ends of edges may be connected.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PathPdfs {
    pub from_camera: Vec<f32>,
    pub from_light: Vec<f32>,
}

impl<'a> PathView<'a> {
    pub fn whole(vertices: &'a [Vertex]) -> PathView<'a> {
        PathView { camera: vertices, light: &[] }
    }

    pub fn len(&self) -> usize {
        self.camera.len() + self.light.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Vertex x_i.
    pub fn get(&self, i: usize) -> &'a Vertex {
        if i < self.camera.len() {
            &self.camera[i]
        } else {
            &self.light[self.len() - 1 - i]
        }
    }

    /// The measurement contribution f(X) = W(x_0→x_1) · Π G(x_i, x_{i+1}) · Π ρ_i · L_e(x_{n−1}→x_{n−2}),
    /// without visibility (callers test it, or know it from tracing). At vertices marked `delta` the
    /// Dirac lobe's coefficient stands in for the BSDF (`Vertex::dirac_lobe`): a value only meaningful
    /// in ratios with densities that carry the same deltas.
    pub fn contribution(&self, scene: &Scene) -> Spectrum {
        let (colour, scale) = self.contribution_scaled(scene);
        colour * scale as f32
    }

    /// f(X) as `colour · scale`, for paths whose f lies outside f32's range. In product area measure f
    /// carries one 1/d² and one BSDF peak per vertex, so a path bouncing inside a small near-specular
    /// gem can leave f32's range within a few dozen vertices (jewelry: the diamond's trapped light),
    /// while the ratios Metropolis forms from it stay O(1). The product is formed in f64, the
    /// factors of each vertex together; `scale` is 1 whenever the f32 value is comfortably in range, so
    /// ordinary paths keep their exact f32 contribution.
    pub fn contribution_scaled(&self, scene: &Scene) -> (Spectrum, f64) {
        let n = self.len();
        if n < 2 || self.get(0).kind != VertexKind::Camera {
            return (Spectrum::ZERO, 1.0);
        }
        let (x0, x1) = (self.get(0), self.get(1));
        let mut f = glam::DVec3::splat(scene.camera.importance(x0.direction_to(x1)) as f64);
        for i in 0..n - 1 {
            f *= geometry_term(self.get(i), self.get(i + 1)) as f64;
            if i + 1 < n - 1 {
                let v = self.get(i + 1);
                f *= v
                    .scatter_factor(scene, v.direction_to(self.get(i)), v.direction_to(self.get(i + 2)))
                    .as_dvec3();
            }
        }
        let (last, before) = (self.get(n - 1), self.get(n - 2));
        f *= last.emitted(scene, last.direction_to(before)).as_dvec3();
        let narrow = f.as_vec3();
        let peak = f.max_element();
        // Non-finite stays non-finite (callers reject it); f32 keeps ~7 digits down to 1e-38, and the
        // margin leaves room for the callers' products.
        if !f.is_finite() || !(peak > 0.0) || (1e-30..=1e30).contains(&peak) {
            return (narrow, 1.0);
        }
        ((f / peak).as_vec3(), peak)
    }

    /// Film position of the path (where x_1 is seen from the camera).
    pub fn film_position(&self, scene: &Scene) -> Option<Vec2> {
        if self.len() < 2 {
            return None;
        }
        scene.camera.film_position(self.get(0).direction_to(self.get(1)))
    }

    /// Area density at `next` of sampling it from `cur`, which was reached from `prev` (`None` when
    /// `cur` is the endpoint the sub-path starts from). This is the one definition every strategy's
    /// density is built from.
    pub fn density(
        scene: &Scene,
        prev: Option<&Vertex>,
        cur: &Vertex,
        next: &Vertex,
        mode: TransportMode,
    ) -> f32 {
        match (prev, cur.kind) {
            (None, VertexKind::Camera) => {
                let pdf = scene.camera.pdf_dir(cur.direction_to(next));
                cur.convert_density(pdf, next, scene)
            }
            (None, _) => cur.pdf_light_emission(scene, next),
            (Some(prev), VertexKind::Surface) => {
                let pdf = cur.pdf_bsdf(scene, cur.direction_to(prev), cur.direction_to(next), mode);
                cur.convert_density(pdf, next, scene)
            }
            (Some(_), _) => 0.0,
        }
    }

    /// Both densities of every vertex, computed from scratch on this path.
    pub fn pdfs(&self, scene: &Scene) -> PathPdfs {
        self.densities(scene, |prev, cur, next, mode| Self::density(scene, prev, cur, next, mode))
    }

    /// Both densities of every vertex as `pdfs` computes them, but with the Dirac convention of
    /// path-space Metropolis (Veach 1997, §8.3.2): the successor of a `delta` vertex, sampled through its
    /// Dirac lobe, gets that lobe's selection probability (`Vertex::dirac_lobe`, converted to area) instead
    /// of the BSDF density, which is zero there. Every product of these densities then carries the same
    /// deltas as f(X) evaluated with the lobe coefficients, so ratios of f to them are meaningful.
    pub fn dirac_pdfs(&self, scene: &Scene) -> PathPdfs {
        self.densities(scene, |prev, cur, next, mode| match prev {
            Some(prev) if cur.delta => cur
                .dirac_lobe(scene, cur.direction_to(prev), cur.direction_to(next), mode)
                .map_or(0.0, |(_, prob)| cur.convert_density(prob, next, scene)),
            _ => Self::density(scene, prev, cur, next, mode),
        })
    }

    /// One pass in each direction: `step(prev, cur, next, mode)` is the area density at `next` of
    /// sampling it from `cur`, reached from `prev`.
    fn densities(
        &self,
        scene: &Scene,
        step: impl Fn(Option<&Vertex>, &Vertex, &Vertex, TransportMode) -> f32,
    ) -> PathPdfs {
        let n = self.len();
        let mut from_camera = vec![0.0; n];
        let mut from_light = vec![0.0; n];
        if n == 0 {
            return PathPdfs { from_camera, from_light };
        }
        from_camera[0] = 1.0;
        for (i, pdf) in from_camera.iter_mut().enumerate().skip(1) {
            let prev = (i >= 2).then(|| self.get(i - 2));
            *pdf = step(prev, self.get(i - 1), self.get(i), TransportMode::Radiance);
        }
        from_light[n - 1] = self.get(n - 1).pdf_light_origin(scene);
        for i in (0..n - 1).rev() {
            let prev = (i + 2 < n).then(|| self.get(i + 2));
            from_light[i] = step(prev, self.get(i + 1), self.get(i), TransportMode::Importance);
        }
        PathPdfs { from_camera, from_light }
    }

    /// True if strategy (s = n − t, t) could have produced this path: its connection edge joins two
    /// connectible vertices, or for s = 0 the camera path hit an emitter that rays can hit.
    pub fn strategy_possible(&self, scene: &Scene, t: usize) -> bool {
        let n = self.len();
        if t == 0 || t > n {
            return false;
        }
        if t == n {
            let last = self.get(n - 1);
            return last.light.is_some() && !last.is_delta_light(scene);
        }
        let (a, b) = (self.get(t - 1), self.get(t));
        let camera_to_environment = a.kind == VertexKind::Camera && b.kind == VertexKind::InfiniteLight;
        a.connectible() && b.connectible() && !camera_to_environment
    }

    /// Density of strategy (s = n − t, t): the camera side samples x_0 … x_{t−1}, the light side the rest.
    pub fn strategy_pdf(pdfs: &PathPdfs, t: usize) -> f64 {
        let cam: f64 = pdfs.from_camera[..t].iter().map(|&p| p as f64).product();
        let light: f64 = pdfs.from_light[t..].iter().map(|&p| p as f64).product();
        cam * light
    }
}

/// The MIS weight of strategy t (s = n − t) on a path with densities `pdfs`: p_t^β / Σ p_{t'}^β over
/// the possible strategies, computed as products of density ratios so long paths do not underflow.
/// Zero densities next to Dirac vertices stand for a delta factor that appears in both strategies of a
/// ratio, and are treated as 1 (as in pbrt's BDPT).
pub fn mis_weight(scene: &Scene, path: &PathView, pdfs: &PathPdfs, t: usize, heuristic: MisHeuristic) -> f32 {
    mis_weight_limited(scene, path, pdfs, t, heuristic, usize::MAX)
}

/// `mis_weight` over the strategies with at most `max_light` light-side vertices (s ≤ max_light),
/// for a BDPT whose light sub-paths are capped (`Bdpt::max_light_vertices`).
pub fn mis_weight_limited(
    scene: &Scene,
    path: &PathView,
    pdfs: &PathPdfs,
    t: usize,
    heuristic: MisHeuristic,
    max_light: usize,
) -> f32 {
    let n = path.len();
    let remap = |x: f32| if x != 0.0 { x as f64 } else { 1.0 };
    let power = |r: f64| match heuristic {
        MisHeuristic::Balance => r,
        MisHeuristic::Power => r * r,
    };
    let mut sum = 0.0f64;
    // Strategies with fewer camera vertices: x_i moves to the light side.
    let mut ratio = 1.0f64;
    for i in (1..t).rev() {
        if n - i > max_light {
            break;
        }
        ratio *= remap(pdfs.from_light[i]) / remap(pdfs.from_camera[i]);
        if path.strategy_possible(scene, i) {
            sum += power(ratio);
        }
    }
    // Strategies with more camera vertices: x_i moves to the camera side.
    ratio = 1.0;
    for i in t..n {
        ratio *= remap(pdfs.from_camera[i]) / remap(pdfs.from_light[i]);
        if path.strategy_possible(scene, i + 1) {
            sum += power(ratio);
        }
    }
    let w = 1.0 / (1.0 + sum);
    if w.is_finite() {
        w as f32
    } else {
        0.0
    }
}
