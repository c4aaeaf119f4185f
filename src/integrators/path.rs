//! Unidirectional path tracer with next-event estimation and multiple importance sampling
//! (power heuristic, Veach 1997 §9.2) between light sampling and BSDF sampling, and Russian roulette
//! on throughput·η² as Mitsuba 3's `path` does, so the two renderers agree on every scene.

use crate::bsdf::{BsdfContext, TransportMode};
use crate::geometry::{Ray, Vec3};
use crate::render::{DepthLimits, PixelIntegrator, SampleCounters, SampleOutput};
use crate::sampling::{power_heuristic, roulette, Sampler};
use crate::scene::Scene;
use crate::spectrum::Spectrum;

pub struct PathTracer {
    pub limits: DepthLimits,
    pub hide_emitters: bool,
    /// Shortest path kept, in segments (1 keeps everything; 3 keeps indirect light only).
    pub min_depth: i32,
}

/// What the previous vertex needs to weight emission found by BSDF sampling.
struct PrevVertex {
    p: Vec3,
    bsdf_pdf: f32,
    delta: bool,
}

impl PathTracer {
    fn allows(&self, segments: i32) -> bool {
        self.limits.max_depth < 0 || segments <= self.limits.max_depth
    }

    fn keeps(&self, segments: i32) -> bool {
        segments >= self.min_depth
    }

    /// MIS weight of emission reached by BSDF sampling from `prev`; `light_pdf` gives the density with
    /// which light sampling at `prev` would have produced the same point.
    fn emission_weight(&self, prev: &Option<PrevVertex>, light_pdf: impl FnOnce(&PrevVertex) -> f32) -> f32 {
        match prev {
            None if self.hide_emitters => 0.0,
            None => 1.0,
            Some(pv) if pv.delta => 1.0,
            Some(pv) => power_heuristic(pv.bsdf_pdf, light_pdf(pv)),
        }
    }

    /// Light sampling at a surface point; returns the MIS-weighted contribution (without throughput).
    fn direct_light(
        &self,
        scene: &Scene,
        si: &crate::scene::SurfaceInteraction,
        bsdf: &dyn crate::bsdf::Bsdf,
        wi_local: Vec3,
        sampler: &mut Sampler,
        counters: &mut SampleCounters,
    ) -> Spectrum {
        let u_light = sampler.next_1d();
        let u = sampler.next_2d();
        let Some((li, pmf, _)) = scene.light_selector.sample(u_light) else {
            return Spectrum::ZERO;
        };
        let light = &scene.lights[li];
        let Some(ls) = light.sample_li(si.p, u, scene.radius()) else {
            return Spectrum::ZERO;
        };
        let ctx = &BsdfContext { mode: TransportMode::Radiance, uv: si.uv };
        let wo_local = si.frame.to_local(ls.wi);
        let f = bsdf.eval(ctx, wi_local, wo_local) * wo_local.z.abs();
        if f == Spectrum::ZERO {
            return Spectrum::ZERO;
        }
        counters.rays += 1;
        counters.shadow_rays += 1;
        let blocked = if ls.dist.is_finite() {
            scene.occluded_between(si.p, si.offset(), ls.p, Vec3::ZERO)
        } else {
            scene.occluded_dir(si.p, si.offset(), ls.wi)
        };
        if blocked {
            return Spectrum::ZERO;
        }
        let light_pdf = pmf * ls.pdf;
        let weight =
            if ls.is_delta { 1.0 } else { power_heuristic(light_pdf, bsdf.pdf(ctx, wi_local, wo_local)) };
        f * ls.radiance * (weight / light_pdf)
    }
}

impl PixelIntegrator for PathTracer {
    fn name(&self) -> &'static str {
        "pt"
    }

    fn li(&self, scene: &Scene, camera_ray: &Ray, sampler: &mut Sampler, out: &mut SampleOutput) -> Spectrum {
        let counters = &mut out.counters;
        let mut radiance = Spectrum::ZERO;
        let mut throughput = Spectrum::ONE;
        // Accumulated relative IOR: Russian roulette judges throughput·η² so refraction into a denser
        // medium (which scales radiance by 1/η²) does not kill paths prematurely.
        let mut eta = 1.0f32;
        let mut ray = *camera_ray;
        let mut prev: Option<PrevVertex> = None;
        let mut segments = 0;
        loop {
            counters.rays += 1;
            segments += 1;
            let Some(si) = scene.intersect(&ray) else {
                let infinite = if self.keeps(segments) { &scene.infinite_lights[..] } else { &[] };
                for &li in infinite {
                    let light = &scene.lights[li];
                    let le = light.eval_infinite(ray.dir);
                    let weight = self.emission_weight(&prev, |_| {
                        scene.light_selector.pmf(li) * light.pdf_infinite(ray.dir)
                    });
                    radiance += throughput * le * weight;
                }
                break;
            };

            if let Some((li, area)) = scene.area_light(si.shape).filter(|_| self.keeps(segments)) {
                let sp = si.light_point();
                let le = area.emitted(&sp, si.wi);
                if le != Spectrum::ZERO {
                    let weight = self.emission_weight(&prev, |pv| {
                        scene.light_selector.pmf(li) * area.pdf_li(pv.p, si.p, si.ng)
                    });
                    radiance += throughput * le * weight;
                }
            }

            if !self.allows(segments + 1) {
                break;
            }

            let bsdf = scene.shapes[si.shape].bsdf.as_ref();
            let ctx = BsdfContext { mode: TransportMode::Radiance, uv: si.uv };
            let wi_local = si.frame.to_local(si.wi);

            if bsdf.lobes().has_smooth() && !scene.light_selector.is_empty() && self.keeps(segments + 1) {
                radiance += throughput * self.direct_light(scene, &si, bsdf, wi_local, sampler, counters);
            }

            let u_lobe = sampler.next_1d();
            let u = sampler.next_2d();
            let Some(bs) = bsdf.sample(&ctx, wi_local, u_lobe, u) else {
                break;
            };
            if !(bs.pdf > 0.0) || !bs.weight.is_finite() || bs.weight == Spectrum::ZERO {
                break;
            }
            let wo = si.frame.to_world(bs.wo);
            throughput *= bs.weight;
            if bs.lobe.contains(crate::bsdf::BsdfLobe::TRANSMISSION) {
                eta *= bs.eta;
            }
            prev = Some(PrevVertex { p: si.p, bsdf_pdf: bs.pdf, delta: bs.lobe.is_delta() });

            if segments >= self.limits.rr_depth {
                let q = roulette::survival_probability(throughput.max_element() * eta * eta);
                if !(sampler.next_1d() < q) {
                    break;
                }
                throughput /= q;
            }
            ray = si.spawn_ray(wo);
        }
        radiance
    }
}
