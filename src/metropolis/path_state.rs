//! The state of a path-space Markov chain (Veach & Guibas 1997): one full path x_0 (camera) … x_k
//! (emitter) of `path::Vertex`, its measurement contribution f(X) in product area measure and its film
//! position. Every path-space mutation (bidirectional, perturbations, manifold, HSLT) maps one to another.

use super::driver::{CountsRays, FilmState};
use super::ChainState;
use crate::geometry::Vec2;
use crate::integrators::Bdpt;
use crate::path::{PathView, Vertex, VertexKind};
use crate::render::{SampleCounters, Splat};
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// A light-carrying path. Invariant: built by `PathState::new`, so `contribution` is f(X) of
/// `vertices` (visibility checked by whoever built the vertices) and `film` is inside the image.
/// Vertices marked `delta` scattered through a Dirac lobe and are evaluated with its coefficient
/// (`Vertex::dirac_lobe`); mutations keep that flag meaningful (a specular vertex stays specular).
#[derive(Clone, Debug)]
pub struct PathState {
    pub vertices: Vec<Vertex>,
    /// f(X) = `contribution` · `scale` (`PathView::contribution_scaled`): `scale` is 1 unless f lies
    /// outside f32's range, as on long paths through small near-specular objects.
    pub contribution: Spectrum,
    pub scale: f64,
    pub film: Vec2,
}

impl PathState {
    /// Evaluates a path whose edges are known to be unoccluded. `None` if it is not a camera-to-emitter
    /// path, leaves the image, or carries nothing (f = 0 or not finite).
    pub fn new(scene: &Scene, vertices: Vec<Vertex>) -> Option<PathState> {
        let n = vertices.len();
        if n < 2 || vertices[0].kind != VertexKind::Camera || vertices[n - 1].light.is_none() {
            return None;
        }
        let view = PathView::whole(&vertices);
        let film = view.film_position(scene)?;
        let (w, h) = (scene.film.width as f32, scene.film.height as f32);
        if !(film.x >= 0.0 && film.y >= 0.0 && film.x < w && film.y < h) {
            return None;
        }
        let (contribution, scale) = view.contribution_scaled(scene);
        if !contribution.is_finite()
            || contribution.min_element() < 0.0
            || contribution.max_element() <= 0.0
            || !(scale.is_finite() && scale > 0.0)
        {
            return None;
        }
        Some(PathState { vertices, contribution, scale, film })
    }

    /// luminance(f(X)) in f64, with the scale applied.
    pub fn luminance(&self) -> f64 {
        crate::spectrum::luminance(self.contribution) as f64 * self.scale
    }

    pub fn view(&self) -> PathView<'_> {
        PathView::whole(&self.vertices)
    }

    /// Number of vertices k + 1.
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }
}

impl ChainState for PathState {
    fn contribution(&self) -> Spectrum {
        self.contribution
    }

    fn scale(&self) -> f64 {
        self.scale
    }
}

impl FilmState for PathState {
    fn splat(&self, weight: f64, out: &mut Vec<Splat>) {
        // weight holds 1/target, so weight · scale is of the order of 1/|contribution|.
        out.push(Splat {
            pos: self.film,
            value: self.contribution * (weight * self.scale) as f32,
            layer: None,
        });
    }
}

/// What the path-space mutations of one chain share: the scene, the BDPT whose depth limits and
/// random walks bound and regenerate paths, and the chain's ray counter. Never shared between chains.
pub struct PathContext<'a> {
    pub scene: &'a Scene,
    pub bdpt: &'a Bdpt,
    pub counters: SampleCounters,
}

impl<'a> PathContext<'a> {
    pub fn new(scene: &'a Scene, bdpt: &'a Bdpt) -> PathContext<'a> {
        PathContext { scene, bdpt, counters: SampleCounters::default() }
    }

    /// Most vertices a path may have (the depth limit), so mutations never leave the space the
    /// seeding pass and BDPT integrate over.
    pub fn max_vertices(&self) -> usize {
        self.bdpt.max_path_vertices()
    }
}

impl CountsRays for PathContext<'_> {
    fn rays(&self) -> u64 {
        self.counters.rays
    }

    fn shadow_rays(&self) -> u64 {
        self.counters.shadow_rays
    }
}
