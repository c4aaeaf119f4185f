//! Scene loading: Mitsuba XML (both 3.x and 0.6 spellings) into plugin properties, then into the
//! render-ready scene: world-space meshes, BSDFs, lights, sensor and film, built only as far as the
//! scene needs them (no texture system without bitmaps, no light structures for absent light types).

mod interaction;
pub mod shapes;
pub mod xml;

pub use crate::props::{Prop, PropValue, Props, SceneError, SrcLoc};
pub use interaction::{surface_derivatives, SurfaceDerivatives, SurfaceInteraction};

use crate::accel::{AccelKind, RayQuery};
use crate::bsdf::{self, Bsdf, BsdfLoader};
use crate::geometry::{Bounds3, Ray, TriangleMesh, Vec3};
use crate::lights::{AreaLight, Light, LightSelector};
use crate::sensor::{FilmSpec, PerspectiveCamera};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A surface in the scene: its triangles, how it scatters and whether it emits.
#[derive(Debug)]
pub struct Shape {
    pub id: String,
    pub mesh: Arc<TriangleMesh>,
    pub bsdf: Arc<dyn Bsdf>,
    /// Index into `Scene::lights` of this shape's area emitter.
    pub light: Option<usize>,
}

/// The `<integrator>` element's settings, in Mitsuba 3's meaning: `max_depth` is the longest path in
/// segments (1 = directly visible emitters only, -1 = unbounded), Russian roulette from `rr_depth` on.
#[derive(Clone, Debug, PartialEq)]
pub struct IntegratorSpec {
    pub kind: String,
    pub max_depth: i32,
    pub rr_depth: i32,
    pub hide_emitters: bool,
}

impl Default for IntegratorSpec {
    fn default() -> Self {
        IntegratorSpec { kind: "path".into(), max_depth: -1, rr_depth: 5, hide_emitters: false }
    }
}

/// What a scene uses, so the renderer builds only that and `hslt info` can report it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneFeatures {
    pub triangles: usize,
    pub bsdf_types: Vec<String>,
    pub light_types: Vec<String>,
    pub textures: usize,
    pub has_delta_bsdf: bool,
    pub has_glossy_bsdf: bool,
    pub has_transmission: bool,
}

impl SceneFeatures {
    /// Specular or glossy vertices make the manifold machinery relevant; an all-diffuse scene never needs it.
    pub fn needs_manifold_walk(&self) -> bool {
        self.has_delta_bsdf || self.has_glossy_bsdf
    }
}

pub struct Scene {
    pub path: PathBuf,
    pub shapes: Vec<Shape>,
    pub lights: Vec<Light>,
    pub light_selector: LightSelector,
    /// Indices of infinite lights (constant, envmap), looked up when a ray escapes.
    pub infinite_lights: Vec<usize>,
    pub camera: PerspectiveCamera,
    pub film: FilmSpec,
    pub integrator: IntegratorSpec,
    pub spp: u32,
    pub bounds: Bounds3,
    pub features: SceneFeatures,
    pub warnings: Vec<String>,
    accel: Box<dyn RayQuery>,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene").field("path", &self.path).field("shapes", &self.shapes.len()).finish()
    }
}

/// Options that change how a scene is built, not what it contains.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    pub defines: Vec<(String, String)>,
    pub accel: AccelKind,
}

impl Scene {
    /// Loads and builds a scene file.
    pub fn load(path: &Path, options: &LoadOptions) -> anyhow::Result<Scene> {
        let root = xml::parse_file(path, &options.defines)?;
        let base_dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let mut builder = Builder::new(options.accel);
        for (_, obj) in root.objects() {
            builder.add(obj, &base_dir)?;
        }
        builder.finish(path, &root, options)
    }

    /// Builds a scene from XML text; `path` names it in errors and anchors relative file references.
    pub fn load_str(text: &str, path: &Path, options: &LoadOptions) -> anyhow::Result<Scene> {
        let root = xml::parse_str(text, path, &options.defines)?;
        let base_dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let mut builder = Builder::new(options.accel);
        for (_, obj) in root.objects() {
            builder.add(obj, &base_dir)?;
        }
        builder.finish(path, &root, options)
    }

    pub fn accel(&self) -> &dyn RayQuery {
        self.accel.as_ref()
    }

    /// Wraps or swaps the ray-query backend (used to instrument it for benchmarks).
    pub fn replace_accel(&mut self, f: impl FnOnce(Box<dyn RayQuery>) -> Box<dyn RayQuery>) {
        let placeholder: Box<dyn RayQuery> = Box::new(crate::accel::NoGeometry);
        let inner = std::mem::replace(&mut self.accel, placeholder);
        self.accel = f(inner);
    }

    /// Radius of the scene's bounding sphere (at least 1e-3 so degenerate scenes stay finite).
    pub fn radius(&self) -> f32 {
        self.bounds.radius().max(1e-3)
    }

    /// The first surface hit by `ray`, with its local geometry.
    pub fn intersect(&self, ray: &Ray) -> Option<SurfaceInteraction> {
        let hit = self.accel.intersect(ray)?;
        SurfaceInteraction::from_hit(self, ray, &hit)
    }

    /// True if the segment from `a` to `b` is blocked; both ends are moved off their surfaces by
    /// their offsets (normal times `ray_epsilon`, as `SurfaceInteraction::offset` and
    /// `Vertex::offset` give; zero for point lights and the camera).
    pub fn occluded_between(&self, a: Vec3, offset_a: Vec3, b: Vec3, offset_b: Vec3) -> bool {
        match Self::shadow_segment(a, offset_a, b, offset_b) {
            Some(ray) => self.accel.occluded(&ray),
            None => true,
        }
    }

    /// The shadow ray `occluded_between` casts, for callers that batch them; `None` for a degenerate
    /// segment (which counts as blocked).
    pub fn shadow_segment(a: Vec3, offset_a: Vec3, b: Vec3, offset_b: Vec3) -> Option<Ray> {
        let d = b - a;
        let oa = crate::geometry::offset_origin(a, offset_a, d);
        let ob = crate::geometry::offset_origin(b, offset_b, -d);
        let seg = ob - oa;
        let len = seg.length();
        if !(len > 0.0) || !len.is_finite() {
            return None;
        }
        Some(Ray { origin: oa, dir: seg / len, tmin: 0.0, tmax: len * (1.0 - 1e-4) })
    }

    /// True if anything blocks the ray leaving `p` (moved off its surface by `offset`, as in
    /// `occluded_between`) along `dir` to infinity.
    pub fn occluded_dir(&self, p: Vec3, offset: Vec3, dir: Vec3) -> bool {
        let o = crate::geometry::offset_origin(p, offset, dir);
        self.accel.occluded(&Ray::new(o, dir))
    }

    /// The area light of a shape, if it emits.
    pub fn area_light(&self, shape: usize) -> Option<(usize, &AreaLight)> {
        let li = self.shapes[shape].light?;
        match &self.lights[li] {
            Light::Area(a) => Some((li, a)),
            _ => None,
        }
    }
}

#[derive(Default)]
struct Builder {
    camera_props: Option<Arc<Props>>,
    integrator: Option<Arc<Props>>,
    shapes: Vec<Shape>,
    lights: Vec<Light>,
    bsdf_cache: HashMap<*const Props, Arc<dyn Bsdf>>,
    features: SceneFeatures,
    warnings: Vec<String>,
    /// Bytes per triangle the ray-query build will take (`AccelKind::build_bytes_per_triangle`).
    build_bytes_per_triangle: u64,
    /// Shapes' bytes added since the memory budget was last checked.
    unchecked_bytes: u64,
}

/// Shapes are checked against the memory budget once this many bytes of them have accumulated (and
/// always before the build): a check reads /proc, too slow to do for each of 10⁵ small shapes.
const BUDGET_CHECK_BYTES: u64 = 64 << 20;

impl Builder {
    fn new(accel: AccelKind) -> Self {
        Builder { build_bytes_per_triangle: accel.build_bytes_per_triangle(), ..Default::default() }
    }

    /// The memory the scene's geometry will need for the ray-query build must still be free: a scene
    /// of a million tessellated spheres is an error naming the shape where it ran out, not an abort
    /// on a failed allocation (#33). Each check covers every triangle so far, as none of the build's
    /// memory is taken before it starts.
    /// `always` is false while shapes are added, true just before the build.
    fn check_geometry_fits(&mut self, added_triangles: usize, always: bool) -> Result<(), String> {
        self.unchecked_bytes += added_triangles as u64 * self.build_bytes_per_triangle;
        if !always && self.unchecked_bytes < BUDGET_CHECK_BYTES {
            return Ok(());
        }
        self.unchecked_bytes = 0;
        let build = self.features.triangles as u64 * self.build_bytes_per_triangle;
        let what = format!("building the ray queries of {} triangles", self.features.triangles);
        crate::resources::check_fits(build, &what)
    }

    fn add(&mut self, obj: &Arc<Props>, base_dir: &Path) -> anyhow::Result<()> {
        match obj.tag.as_str() {
            "sensor" => {
                if self.camera_props.is_some() {
                    return Err(obj.error("only one <sensor> per scene is supported").into());
                }
                self.camera_props = Some(obj.clone());
            }
            "integrator" => self.integrator = Some(obj.clone()),
            "shape" => self.add_shape(obj, base_dir)?,
            "emitter" => {
                let light = Light::from_props(obj, base_dir)?;
                self.note_light(obj);
                self.lights.push(light);
            }
            // Declarations used through <ref>; instantiated where referenced.
            "bsdf" | "texture" => {}
            other => return Err(obj.error(format!("unsupported top-level element <{other}>")).into()),
        }
        Ok(())
    }

    fn note_light(&mut self, props: &Props) {
        if !self.features.light_types.contains(&props.plugin_type) {
            self.features.light_types.push(props.plugin_type.clone());
        }
    }

    fn bsdf_for(&mut self, props: &Arc<Props>, base_dir: &Path) -> Result<Arc<dyn Bsdf>, SceneError> {
        let key = Arc::as_ptr(props);
        if let Some(b) = self.bsdf_cache.get(&key) {
            return Ok(b.clone());
        }
        let b = bsdf::from_props(props, &BsdfLoader { base_dir })?;
        note_bsdf_types(props, &mut self.features);
        let lobes = b.lobes();
        self.features.has_delta_bsdf |= lobes.is_delta();
        self.features.has_glossy_bsdf |= lobes.contains(crate::bsdf::BsdfLobe::GLOSSY);
        self.features.has_transmission |= lobes.contains(crate::bsdf::BsdfLobe::TRANSMISSION);
        self.bsdf_cache.insert(key, b.clone());
        Ok(b)
    }

    fn add_shape(&mut self, obj: &Arc<Props>, base_dir: &Path) -> anyhow::Result<()> {
        let loaded = shapes::load_shape(obj, base_dir)?;
        self.warnings.extend(loaded.warnings);
        let mut mesh = loaded.mesh;
        let id = obj.id.clone().unwrap_or_else(|| format!("shape{}", self.shapes.len()));
        if mesh.name.is_empty() {
            mesh.name = id.clone();
        }
        let mesh = Arc::new(mesh);
        let mut bsdfs = obj.objects_with_tag("bsdf");
        let bsdf = match bsdfs.next() {
            Some(b) => {
                if bsdfs.next().is_some() {
                    return Err(obj.error("a shape takes at most one <bsdf>").into());
                }
                let b = b.clone();
                self.bsdf_for(&b, base_dir)?
            }
            None => {
                // Mitsuba's default material: diffuse with reflectance 0.5.
                let default = Arc::new(Props::new("bsdf", "diffuse", obj.loc.clone()));
                self.bsdf_for(&default, base_dir)?
            }
        };
        let mut light = None;
        let emitters: Vec<_> = obj.objects_with_tag("emitter").cloned().collect();
        if emitters.len() > 1 {
            return Err(obj.error("a shape takes at most one <emitter>").into());
        }
        if let Some(e) = emitters.first() {
            if e.plugin_type != "area" {
                return Err(e.error("only 'area' emitters can be attached to a shape").into());
            }
            let area = AreaLight::from_props(e, mesh.clone(), self.shapes.len())?;
            self.note_light(e);
            light = Some(self.lights.len());
            self.lights.push(Light::Area(area));
        }
        self.features.triangles += mesh.triangle_count();
        self.check_geometry_fits(mesh.triangle_count(), false).map_err(|e| obj.error(e))?;
        self.shapes.push(Shape { id, mesh, bsdf, light });
        Ok(())
    }

    fn finish(mut self, path: &Path, root: &Props, options: &LoadOptions) -> anyhow::Result<Scene> {
        let camera_props =
            self.camera_props.clone().ok_or_else(|| root.error("the scene has no <sensor>"))?;
        let film = match camera_props.objects_with_tag("film").next() {
            Some(f) => FilmSpec::from_props(f)?,
            None => FilmSpec::default(),
        };
        let camera = PerspectiveCamera::from_props(&camera_props, film.width, film.height)?;
        let spp = match camera_props.objects_with_tag("sampler").next() {
            Some(s) => {
                if s.plugin_type != "independent" {
                    self.warnings.push(format!(
                        "{}: sampler '{}' is rendered with independent random numbers",
                        s.loc, s.plugin_type
                    ));
                }
                s.expect_only(&["sample_count", "seed", "jitter"], &[])?;
                let n = s.int("sample_count", 4)?;
                if n < 1 {
                    return Err(s.error_at("sample_count", "sample_count must be at least 1").into());
                }
                n.min(u32::MAX as i64) as u32
            }
            None => 4,
        };
        let integrator = match &self.integrator {
            Some(p) => integrator_spec(p)?,
            None => IntegratorSpec::default(),
        };
        let mut bounds = Bounds3::default();
        for s in &self.shapes {
            bounds = bounds.union(&s.mesh.bounds());
        }
        if bounds.is_empty() {
            bounds.expand(camera.position());
        }
        // The backends borrow the meshes: no copy of the geometry while the structure is built.
        self.check_geometry_fits(0, true).map_err(|e| SceneError::file(path, e))?;
        let meshes: Vec<Arc<TriangleMesh>> = self.shapes.iter().map(|s| Arc::clone(&s.mesh)).collect();
        let accel = crate::accel::build(options.accel, &meshes)?;
        let radius = bounds.radius().max(1e-3);
        let light_selector = LightSelector::new(&self.lights, radius);
        let infinite_lights = (0..self.lights.len()).filter(|&i| self.lights[i].is_infinite()).collect();
        self.features.textures = count_bitmaps(root);
        Ok(Scene {
            path: path.to_path_buf(),
            shapes: self.shapes,
            lights: self.lights,
            light_selector,
            infinite_lights,
            camera,
            film,
            integrator,
            spp,
            bounds,
            features: self.features,
            warnings: self.warnings,
            accel,
        })
    }
}

/// Number of distinct bitmap texture elements reachable from the scene (a shared `<ref>` counts once).
fn count_bitmaps(root: &Props) -> usize {
    fn walk(p: &Arc<Props>, seen: &mut Vec<*const Props>, bitmaps: &mut usize) {
        let key = Arc::as_ptr(p);
        if seen.contains(&key) {
            return;
        }
        seen.push(key);
        if p.tag == "texture" && p.plugin_type == "bitmap" {
            *bitmaps += 1;
        }
        for (_, child) in p.objects() {
            walk(child, seen, bitmaps);
        }
    }
    let (mut seen, mut bitmaps) = (Vec::new(), 0);
    for (_, obj) in root.objects() {
        walk(obj, &mut seen, &mut bitmaps);
    }
    bitmaps
}

fn note_bsdf_types(props: &Props, features: &mut SceneFeatures) {
    if !features.bsdf_types.contains(&props.plugin_type) {
        features.bsdf_types.push(props.plugin_type.clone());
    }
    for nested in props.objects_with_tag("bsdf") {
        note_bsdf_types(nested, features);
    }
}

fn integrator_spec(p: &Props) -> Result<IntegratorSpec, SceneError> {
    p.expect_only(&["max_depth", "rr_depth", "hide_emitters"], &[])?;
    let max_depth = p.int("max_depth", -1)?;
    let rr_depth = p.int("rr_depth", 5)?;
    if max_depth < -1 || max_depth == 0 {
        return Err(p.error_at("max_depth", "max_depth must be -1 (unbounded) or at least 1"));
    }
    if rr_depth < 1 {
        return Err(p.error_at("rr_depth", "rr_depth must be at least 1"));
    }
    Ok(IntegratorSpec {
        kind: p.plugin_type.clone(),
        max_depth: max_depth.clamp(-1, i32::MAX as i64) as i32,
        rr_depth: rr_depth.min(i32::MAX as i64) as i32,
        hide_emitters: p.bool("hide_emitters", false)?,
    })
}
