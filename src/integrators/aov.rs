//! Auxiliary outputs for denoisers (`--aov albedo,normal,depth`; Intel Open Image Denoise's albedo
//! and normal inputs, Blender's depth pass): a pixel pass of its own beside any integrator, so the
//! Metropolis ones get them too. Each camera ray follows delta (mirror, smooth glass) bounces to the
//! first surface that is not purely specular, as OIDN asks, and records there:
//!
//! | layer | channels | value |
//! |---|---|---|
//! | `albedo` | R, G, B | directional albedo ∫ f·cos dω of that surface for the viewing direction, estimated from `ALBEDO_SAMPLES` BSDF samples, times the tint of the specular bounces before it, in [0, 1]; 0 where the ray leaves the scene |
//! | `normal` | X, Y, Z | world-space unit shading normal there; 0 where the ray leaves the scene |
//! | `depth` | Z | distance along the camera ray to the first surface it meets (before any bounce); `MISS_DEPTH` where it meets none |

use crate::bsdf::{BsdfContext, BsdfSample, TransportMode};
use crate::geometry::Ray;
use crate::render::{PixelIntegrator, SampleOutput};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// Depth of a ray that meets no surface: finite (no Inf reaches an image) and far beyond any scene,
/// Blender's value for the background.
pub const MISS_DEPTH: f32 = 1e10;

/// BSDF samples per camera sample for the albedo: the pass runs few camera samples, and OIDN works
/// best with a clean albedo.
const ALBEDO_SAMPLES: usize = 4;

/// Delta bounces followed before giving up on finding a non-specular surface.
const MAX_SPECULAR_BOUNCES: usize = 8;

/// The auxiliary outputs one can ask for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Aov {
    Albedo,
    Normal,
    Depth,
}

impl Aov {
    pub const ALL: [Aov; 3] = [Aov::Albedo, Aov::Normal, Aov::Depth];

    pub fn name(self) -> &'static str {
        match self {
            Aov::Albedo => "albedo",
            Aov::Normal => "normal",
            Aov::Depth => "depth",
        }
    }

    /// The EXR channel names of the layer (OIDN's and Blender's conventions).
    pub fn channels(self) -> &'static [&'static str] {
        match self {
            Aov::Albedo => &["R", "G", "B"],
            Aov::Normal => &["X", "Y", "Z"],
            Aov::Depth => &["Z"],
        }
    }

    /// Parses `albedo,normal,depth` (any subset, any order, no repeats).
    pub fn parse_list(list: &str) -> Result<Vec<Aov>, String> {
        let mut aovs = Vec::new();
        for name in list.split(',').map(str::trim) {
            let aov = Aov::ALL
                .into_iter()
                .find(|a| a.name() == name)
                .ok_or_else(|| format!("unknown AOV '{name}' (available: albedo, normal, depth)"))?;
            if aovs.contains(&aov) {
                return Err(format!("AOV '{name}' is listed twice"));
            }
            aovs.push(aov);
        }
        Ok(aovs)
    }
}

/// The pass: its film layers are the requested AOVs in order; its radiance is zero.
pub struct AovPass {
    pub aovs: Vec<Aov>,
}

/// What a camera ray finds at the first non-specular surface.
struct FirstHit {
    albedo: Spectrum,
    normal: Spectrum,
    depth: f32,
}

impl AovPass {
    fn first_hit(&self, scene: &Scene, camera_ray: &Ray, sampler: &mut Sampler, rays: &mut u64) -> FirstHit {
        let miss = |depth: f32| FirstHit { albedo: Spectrum::ZERO, normal: Spectrum::ZERO, depth };
        let mut ray = *camera_ray;
        let mut tint = Spectrum::ONE;
        let mut depth = MISS_DEPTH;
        for bounce in 0..=MAX_SPECULAR_BOUNCES {
            *rays += 1;
            let Some(si) = scene.intersect(&ray) else { return miss(depth) };
            if bounce == 0 {
                depth = si.t;
            }
            let bsdf = scene.shapes[si.shape].bsdf.as_ref();
            let ctx = BsdfContext { mode: TransportMode::Radiance, uv: si.uv };
            let wi_local = si.frame.to_local(si.wi);
            if !bsdf.lobes().is_delta() {
                let mut albedo = Spectrum::ZERO;
                for _ in 0..ALBEDO_SAMPLES {
                    let (u_lobe, u) = (sampler.next_1d(), sampler.next_2d());
                    if let Some(bs) = bsdf.sample(&ctx, wi_local, u_lobe, u) {
                        let w = scattered_energy(&bs);
                        if bs.pdf > 0.0 && w.is_finite() {
                            albedo += w;
                        }
                    }
                }
                let albedo = (tint * albedo / ALBEDO_SAMPLES as f32).clamp(Spectrum::ZERO, Spectrum::ONE);
                return FirstHit { albedo, normal: si.frame.n.normalize_or_zero(), depth };
            }
            let Some(bs) = bsdf.sample(&ctx, wi_local, sampler.next_1d(), sampler.next_2d()) else {
                return miss(depth);
            };
            let w = scattered_energy(&bs);
            if !(bs.pdf > 0.0 && w.is_finite()) {
                return miss(depth);
            }
            tint *= w;
            ray = si.spawn_ray(si.frame.to_world(bs.wo));
        }
        miss(depth)
    }
}

/// The fraction of energy a BSDF sample carries: its weight without the 1/η² that radiance mode puts on
/// refraction (η is 1 for reflection, so reflected samples keep their weight).
fn scattered_energy(bs: &BsdfSample) -> Spectrum {
    bs.weight * (bs.eta * bs.eta)
}

impl PixelIntegrator for AovPass {
    fn name(&self) -> &'static str {
        "aov"
    }

    fn li(&self, scene: &Scene, ray: &Ray, sampler: &mut Sampler, out: &mut SampleOutput) -> Spectrum {
        let hit = self.first_hit(scene, ray, sampler, &mut out.counters.rays);
        for (layer, aov) in self.aovs.iter().enumerate() {
            let value = match aov {
                Aov::Albedo => hit.albedo,
                Aov::Normal => hit.normal,
                Aov::Depth => Spectrum::splat(hit.depth),
            };
            out.layer_values.push((layer as u16, value));
        }
        Spectrum::ZERO
    }

    fn layers(&self) -> Vec<String> {
        self.aovs.iter().map(|a| a.name().to_string()).collect()
    }

    fn signed_layers(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_parse_in_order_and_reject_unknown_or_repeated_names() {
        assert_eq!(Aov::parse_list("depth,albedo"), Ok(vec![Aov::Depth, Aov::Albedo]));
        assert_eq!(Aov::parse_list("albedo, normal ,depth").unwrap().len(), 3);
        assert!(Aov::parse_list("albedo,position").unwrap_err().contains("position"));
        assert!(Aov::parse_list("normal,normal").unwrap_err().contains("twice"));
        assert!(Aov::parse_list("").is_err());
    }
}
