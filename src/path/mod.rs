//! Path space (Veach 1997, ch. 8): a light path is a sequence of vertices x_0 … x_k from the sensor
//! (x_0) to an emitter (x_k). One `Vertex` type serves bidirectional path tracing, every Metropolis
//! mutation and the manifold walk: it carries the local geometry (position, normals, shading frame,
//! surface derivatives), the scattering class, and the area-measure densities of being sampled from the
//! camera side and from the light side, so any (s, t) strategy's density can be evaluated on a path.

mod eval;
pub mod walk;

pub use eval::{mis_weight, mis_weight_limited, MisHeuristic, PathPdfs, PathView};

use crate::bsdf::{Bsdf, BsdfContext, BsdfSample, TransportMode};
use crate::geometry::{Frame, Vec2, Vec3};
use crate::lights::{AreaLight, EmissionSample, Light, SurfacePoint};
use crate::scene::{Scene, SurfaceDerivatives, SurfaceInteraction};
use crate::spectrum::Spectrum;

/// What a vertex lies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VertexKind {
    /// The pinhole (x_0).
    Camera,
    /// A scattering surface (possibly emitting: `light` is then set).
    Surface,
    /// A light source endpoint sampled on the light: area, point or spot.
    Light,
    /// An environment endpoint: only a direction. `ng` holds the direction light travels.
    InfiniteLight,
}

/// How a vertex scatters, for the manifold walk and the Metropolis mutations. Glossy keeps its
/// microfacet roughness α so a walk can size its steps and MEMLT can apply its threshold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ScatterClass {
    Diffuse,
    Glossy {
        alpha: f32,
    },
    /// A Dirac BSDF (smooth conductor or dielectric): α = 0.
    Specular,
}

impl ScatterClass {
    /// The class of a BSDF from its smallest roughness over its lobes.
    pub fn of(bsdf: &dyn Bsdf) -> ScatterClass {
        let alpha = bsdf.roughness();
        if alpha <= 0.0 {
            ScatterClass::Specular
        } else if alpha.is_finite() {
            ScatterClass::Glossy { alpha }
        } else {
            ScatterClass::Diffuse
        }
    }
}

/// A path vertex. Directions and densities follow the path convention of `path`: `pdf_from_camera`
/// is the area density of this vertex when the path is traced from the sensor (x_0 side), and
/// `pdf_from_light` when traced from the emitter (x_k side). Zero marks "cannot be sampled so" (and,
/// after a Dirac vertex, a density the MIS ratio treats as cancelling).
#[derive(Clone, Copy, Debug)]
pub struct Vertex {
    pub kind: VertexKind,
    pub p: Vec3,
    /// Geometric normal (camera: the viewing axis; infinite light: the direction light travels; point
    /// and spot lights: zero, meaning "no cosine").
    pub ng: Vec3,
    /// Shading frame (normal, tangent along ∂p/∂u).
    pub frame: Frame,
    pub uv: Vec2,
    /// Surface parameterisation at `p` (zero for the camera and point-like lights).
    pub derivatives: SurfaceDerivatives,
    /// Shape and triangle the vertex lies on (`usize::MAX` when none).
    pub shape: usize,
    pub prim: usize,
    /// Barycentrics in `prim`.
    pub bary: Vec2,
    /// Emitter at this vertex, if any (index into `Scene::lights`).
    pub light: Option<usize>,
    pub class: ScatterClass,
    /// Reached or left through a Dirac lobe (or a Dirac light position): the vertex cannot be an
    /// end of a connection edge.
    pub delta: bool,
    /// The BSDF has a non-Dirac lobe (cached: connections ask for every pair of vertices).
    pub smooth: bool,
    pub pdf_from_camera: f32,
    pub pdf_from_light: f32,
    /// Throughput of the sub-path up to and including the edge into this vertex: its contribution
    /// divided by its density (Veach's α weights).
    pub beta: Spectrum,
    /// How far rays leaving a surface vertex start off it (`geometry::ray_epsilon`); 0 elsewhere.
    pub eps: f32,
}

const NO_SHAPE: usize = usize::MAX;

fn no_derivatives() -> SurfaceDerivatives {
    SurfaceDerivatives {
        dpdu: Vec3::ZERO,
        dpdv: Vec3::ZERO,
        dndu: Vec3::ZERO,
        dndv: Vec3::ZERO,
        from_uv: false,
    }
}

impl Vertex {
    /// The pinhole endpoint. Its position is a Dirac, so its density is 1 in the MIS ratios.
    pub fn camera(scene: &Scene) -> Vertex {
        let forward = scene.camera.forward();
        Vertex {
            kind: VertexKind::Camera,
            p: scene.camera.position(),
            ng: forward,
            frame: Frame::from_normal(forward),
            uv: Vec2::ZERO,
            derivatives: no_derivatives(),
            shape: NO_SHAPE,
            prim: 0,
            bary: Vec2::ZERO,
            light: None,
            class: ScatterClass::Diffuse,
            delta: false,
            smooth: false,
            pdf_from_camera: 1.0,
            pdf_from_light: 0.0,
            beta: Spectrum::ONE,
            eps: 0.0,
        }
    }

    /// A scattering vertex at a ray hit.
    pub fn surface(scene: &Scene, si: &SurfaceInteraction, beta: Spectrum) -> Vertex {
        let shape = &scene.shapes[si.shape];
        Vertex {
            kind: VertexKind::Surface,
            p: si.p,
            ng: si.ng,
            frame: si.frame,
            uv: si.uv,
            derivatives: si.derivatives(scene),
            shape: si.shape,
            prim: si.prim,
            bary: si.bary,
            light: shape.light,
            class: ScatterClass::of(shape.bsdf.as_ref()),
            delta: false,
            smooth: shape.bsdf.lobes().has_smooth(),
            pdf_from_camera: 0.0,
            pdf_from_light: 0.0,
            beta,
            eps: si.eps,
        }
    }

    /// An emitter endpoint from an emission (or light-sampling) sample of light `light`.
    pub fn light(scene: &Scene, light: usize, es: &EmissionSample, beta: Spectrum, pdf: f32) -> Vertex {
        let l = &scene.lights[light];
        let mut v = Vertex {
            kind: if l.is_infinite() { VertexKind::InfiniteLight } else { VertexKind::Light },
            p: es.p,
            ng: if l.is_infinite() { es.dir } else { es.ng },
            frame: Frame::from_normal(if l.is_infinite() {
                es.dir
            } else {
                es.ng.try_normalize().unwrap_or(Vec3::Z)
            }),
            uv: Vec2::ZERO,
            derivatives: no_derivatives(),
            shape: NO_SHAPE,
            prim: 0,
            bary: Vec2::ZERO,
            light: Some(light),
            class: ScatterClass::Diffuse,
            delta: l.is_delta(),
            smooth: false,
            pdf_from_camera: 0.0,
            pdf_from_light: pdf,
            beta,
            eps: 0.0,
        };
        if let (Light::Area(a), Some(sp)) = (l, &es.surface) {
            v.shape = a.shape;
            v.prim = sp.prim;
            v.bary = sp.bary;
            v.uv = sp.uv;
            v.ng = sp.ng;
            v.derivatives = crate::scene::surface_derivatives(&a.mesh, sp.prim, sp.bary);
            v.frame = Frame::from_normal_tangent(sp.ns, v.derivatives.dpdu);
            v.class = ScatterClass::of(scene.shapes[a.shape].bsdf.as_ref());
            v.eps = crate::geometry::ray_epsilon(v.p, a.mesh.coordinate_scale(sp.prim));
        }
        v
    }

    /// An environment endpoint seen along `dir` from `from` (a camera path escaping the scene).
    pub fn infinite(scene: &Scene, light: usize, from: Vec3, dir: Vec3) -> Vertex {
        let es = EmissionSample {
            p: from + dir * 2.0 * scene.radius(),
            ng: Vec3::ZERO,
            dir: -dir,
            le: Spectrum::ZERO,
            pdf_pos: 0.0,
            pdf_dir: 0.0,
            surface: None,
        };
        Vertex::light(scene, light, &es, Spectrum::ZERO, 0.0)
    }

    pub fn is_surface(&self) -> bool {
        self.shape != NO_SHAPE
    }

    /// The offset of shadow rays leaving this vertex (`geometry::offset_origin`): its geometric
    /// normal times its `eps` on surfaces, zero elsewhere (the camera, point and infinite lights).
    pub fn offset(&self) -> Vec3 {
        if self.is_surface() {
            self.ng * self.eps
        } else {
            Vec3::ZERO
        }
    }

    /// True for Dirac light positions (point, spot): they cannot be hit by a ray.
    pub fn is_delta_light(&self, scene: &Scene) -> bool {
        self.kind == VertexKind::Light && self.light.is_some_and(|l| scene.lights[l].is_delta())
    }

    /// True if this vertex can be the end of a connection edge: it has a non-Dirac way to scatter
    /// (or it is an endpoint that is not itself a Dirac direction).
    pub fn connectible(&self) -> bool {
        match self.kind {
            VertexKind::Camera | VertexKind::Light | VertexKind::InfiniteLight => true,
            VertexKind::Surface => !self.delta && self.smooth,
        }
    }

    pub fn bsdf<'a>(&self, scene: &'a Scene) -> Option<&'a dyn Bsdf> {
        (self.kind == VertexKind::Surface).then(|| scene.shapes[self.shape].bsdf.as_ref())
    }

    /// Unit direction from this vertex towards `other` (for an infinite light: back along its travel).
    pub fn direction_to(&self, other: &Vertex) -> Vec3 {
        match (self.kind, other.kind) {
            (_, VertexKind::InfiniteLight) => -other.ng,
            (VertexKind::InfiniteLight, _) => self.ng,
            _ => (other.p - self.p).normalize_or_zero(),
        }
    }

    /// |cos| between this vertex's geometric normal and `w` (1 where there is no surface).
    pub fn abs_cos(&self, w: Vec3) -> f32 {
        if self.ng == Vec3::ZERO {
            1.0
        } else {
            self.ng.dot(w).abs()
        }
    }

    /// Converts a solid-angle density at this vertex towards `next` into an area density at `next`.
    /// The camera and Dirac lights cannot be reached (0); an environment endpoint is measured by
    /// direction, so the density stays in solid angle.
    pub fn convert_density(&self, pdf_dir: f32, next: &Vertex, scene: &Scene) -> f32 {
        match next.kind {
            VertexKind::Camera => 0.0,
            VertexKind::InfiniteLight => pdf_dir,
            VertexKind::Light if next.is_delta_light(scene) => 0.0,
            _ => {
                let d = next.p - self.p;
                let dist2 = d.length_squared();
                if !(dist2 > 0.0) {
                    return 0.0;
                }
                pdf_dir * next.abs_cos(d / dist2.sqrt()) / dist2
            }
        }
    }

    /// The BSDF at this vertex, f(wi, wo) for transport `mode`, with Veach's shading-normal correction
    /// for importance transport; no cosine.
    pub fn eval_bsdf(&self, scene: &Scene, wi: Vec3, wo: Vec3, mode: TransportMode) -> Spectrum {
        let Some(bsdf) = self.bsdf(scene) else { return Spectrum::ZERO };
        let ctx = BsdfContext { mode, uv: self.uv };
        let f = bsdf.eval(&ctx, self.frame.to_local(wi), self.frame.to_local(wo));
        f * crate::bsdf::shading_normal_correction(mode, wi, wo, self.ng, self.frame.n)
    }

    /// Solid-angle density of the BSDF sampling `wo` given `wi` at this vertex (0 at Dirac vertices).
    pub fn pdf_bsdf(&self, scene: &Scene, wi: Vec3, wo: Vec3, mode: TransportMode) -> f32 {
        match self.bsdf(scene) {
            Some(bsdf) if !self.delta => {
                bsdf.pdf(&BsdfContext { mode, uv: self.uv }, self.frame.to_local(wi), self.frame.to_local(wo))
            }
            _ => 0.0,
        }
    }

    /// The scattering factor of an inner vertex in the area-measure contribution f(X): the radiance BSDF
    /// for light arriving from `to_light` and leaving towards `to_camera`, times |n_s·ω_l| / |n_g·ω_l|
    /// (the geometric cosine of that edge is in the geometry term). At a `delta` vertex the Dirac lobe's
    /// coefficient stands in for the BSDF (see `dirac_lobe`).
    pub fn scatter_factor(&self, scene: &Scene, to_camera: Vec3, to_light: Vec3) -> Spectrum {
        let cos_g = self.ng.dot(to_light).abs();
        if !(cos_g > 0.0) {
            return Spectrum::ZERO;
        }
        let f = if self.delta {
            match self.dirac_lobe(scene, to_camera, to_light, TransportMode::Radiance) {
                Some((f, _)) => f,
                None => return Spectrum::ZERO,
            }
        } else {
            self.eval_bsdf(scene, to_camera, to_light, TransportMode::Radiance)
        };
        f * (self.frame.n.dot(to_light).abs() / cos_g)
    }

    /// The Dirac lobe of this vertex's BSDF on the side of `wo` (reflection or transmission), as
    /// (coefficient, lobe probability): the coefficient is the BSDF with its delta removed in solid
    /// angle (F / |cos θ_o|, with the radiance-mode η² for refraction), the probability is the density
    /// sampling gives that lobe's direction with the same delta removed. Path-space Metropolis
    /// evaluates paths through specular vertices with these: every ratio it forms pairs each vertex's
    /// delta in f with the same delta in a proposal density, so the deltas cancel (Veach 1997, §8.3.2).
    /// The caller vouches that `wo` is the lobe's direction for `wi` (paths are built by tracing or by
    /// a walk that keeps the specular constraint); `None` if the BSDF has no such lobe.
    pub fn dirac_lobe(
        &self,
        scene: &Scene,
        wi: Vec3,
        wo: Vec3,
        mode: TransportMode,
    ) -> Option<(Spectrum, f32)> {
        let bs = self.dirac_sample(scene, wi, self.reflects(wi, wo), mode)?;
        let f = bs.weight * (bs.pdf / bs.wo.z.abs());
        let f = f * crate::bsdf::shading_normal_correction(mode, wi, wo, self.ng, self.frame.n);
        Some((f, bs.pdf))
    }

    /// The BSDF sample of this vertex's Dirac lobe on the `reflect` side of `wi` (local frame), if any.
    fn dirac_sample(
        &self,
        scene: &Scene,
        wi: Vec3,
        reflect: bool,
        mode: TransportMode,
    ) -> Option<BsdfSample> {
        let bsdf = self.bsdf(scene)?;
        let ctx = BsdfContext { mode, uv: self.uv };
        let wi_local = self.frame.to_local(wi);
        // The lobe choice number is opaque to us; its two extremes select the first and the last lobe.
        [0.0, 1.0 - f32::EPSILON].into_iter().find_map(|u_lobe| {
            let bs = bsdf.sample(&ctx, wi_local, u_lobe, Vec2::splat(0.5))?;
            (bs.lobe.is_delta() && (bs.wo.z * wi_local.z > 0.0) == reflect && bs.wo.z != 0.0).then_some(bs)
        })
    }

    /// True if the path scatters at this vertex by reflection (both directions on one side of the
    /// shading normal), false for transmission: the side `dirac_lobe` and `dirac_direction` select.
    pub fn reflects(&self, wi: Vec3, wo: Vec3) -> bool {
        self.frame.to_local(wi).z * self.frame.to_local(wo).z > 0.0
    }

    /// The direction the Dirac lobe of this vertex's BSDF on the `reflect` side sends `wi` to (world
    /// space), chosen as `dirac_lobe` chooses it; `None` if the BSDF has no Dirac lobe on that side.
    /// The perturbations retrace specular chains with it.
    pub fn dirac_direction(
        &self,
        scene: &Scene,
        wi: Vec3,
        reflect: bool,
        mode: TransportMode,
    ) -> Option<Vec3> {
        let bs = self.dirac_sample(scene, wi, reflect, mode)?;
        Some(self.frame.to_world(bs.wo).normalize_or_zero())
    }

    /// This vertex as an area light's surface point.
    fn surface_point(&self) -> SurfacePoint {
        SurfacePoint {
            prim: self.prim,
            bary: self.bary,
            p: self.p,
            ng: self.ng,
            ns: self.frame.n,
            uv: self.uv,
        }
    }

    /// Radiance (or intensity) this vertex emits towards `w` (unit, leaving the vertex).
    pub fn emitted(&self, scene: &Scene, w: Vec3) -> Spectrum {
        let Some(li) = self.light else { return Spectrum::ZERO };
        match &scene.lights[li] {
            Light::Area(a) => a.emitted(&self.surface_point(), w),
            Light::Point(l) => l.intensity,
            Light::Spot(l) => l.intensity * l.falloff(w),
            l @ (Light::Constant { .. } | Light::Env(_)) => l.eval_infinite(-self.ng),
        }
    }

    /// Density with which light sampling (and emission sampling) picks this emitter endpoint: light
    /// choice times the position density (area lights: per area; infinite lights: the direction's
    /// solid-angle density; Dirac positions: 1).
    pub fn pdf_light_origin(&self, scene: &Scene) -> f32 {
        let Some(li) = self.light else { return 0.0 };
        let pmf = scene.light_selector.pmf(li);
        pmf * match &scene.lights[li] {
            Light::Area(a) => a.pdf_area(),
            Light::Point(_) | Light::Spot(_) => 1.0,
            l @ (Light::Constant { .. } | Light::Env(_)) => l.pdf_infinite(-self.ng),
        }
    }

    /// An emission direction drawn at this (kept) emitter endpoint, with the density that
    /// `pdf_light_emission` converts to area: the direction part of `Light::sample_le`. `None` for
    /// infinite lights and non-emitters.
    pub fn sample_emission_direction(&self, scene: &Scene, u: Vec2) -> Option<Vec3> {
        let light = &scene.lights[self.light?];
        let n = match light {
            Light::Area(_) => AreaLight::emitting_normal(&self.surface_point()),
            _ => Vec3::ZERO,
        };
        light.sample_le_dir(n, u).map(|(dir, _)| dir)
    }

    /// Area density at `next` of emission from this emitter endpoint towards it.
    pub fn pdf_light_emission(&self, scene: &Scene, next: &Vertex) -> f32 {
        let Some(li) = self.light else { return 0.0 };
        let light = &scene.lights[li];
        if light.is_infinite() {
            // Start points are uniform on a disk of the scene's radius facing the direction, so the
            // density of hitting `next` is the disk density times the cosine there.
            let r = scene.radius();
            return next.abs_cos(self.ng) / (std::f32::consts::PI * r * r);
        }
        let w = self.direction_to(next);
        let n = match light {
            Light::Area(_) => AreaLight::emitting_normal(&self.surface_point()),
            _ => Vec3::ZERO,
        };
        self.convert_density(light.pdf_le_dir(n, w), next, scene)
    }
}

/// The geometry term between two vertices without visibility: |cos_a| |cos_b| / d², with the
/// conventions of `Vertex::abs_cos` (no cosine at point-like lights) and an environment endpoint
/// contributing only the cosine at the other end.
pub fn geometry_term(a: &Vertex, b: &Vertex) -> f32 {
    match (a.kind, b.kind) {
        (VertexKind::InfiniteLight, _) => b.abs_cos(a.ng),
        (_, VertexKind::InfiniteLight) => a.abs_cos(b.ng),
        _ => {
            let d = b.p - a.p;
            let dist2 = d.length_squared();
            if !(dist2 > 0.0) {
                return 0.0;
            }
            let w = d / dist2.sqrt();
            a.abs_cos(w) * b.abs_cos(w) / dist2
        }
    }
}

/// True if nothing blocks the edge between two vertices.
pub fn visible(scene: &Scene, a: &Vertex, b: &Vertex) -> bool {
    match (a.kind, b.kind) {
        (VertexKind::InfiniteLight, VertexKind::InfiniteLight) => false,
        (_, VertexKind::InfiniteLight) => !scene.occluded_dir(a.p, a.offset(), -b.ng),
        (VertexKind::InfiniteLight, _) => !scene.occluded_dir(b.p, b.offset(), a.ng),
        _ => !scene.occluded_between(a.p, a.offset(), b.p, b.offset()),
    }
}
