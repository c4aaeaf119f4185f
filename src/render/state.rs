//! What a render has done, in a form that adds up: its film with the work behind it (samples per
//! pixel, or the Metropolis chains' mutations and the sums their normalisation b is the mean of), so
//! parts rendered apart (`--part K/N`) and a checkpoint with the run resuming it combine into the
//! image one run of all that work gives. docs/mlt.md ("Merging renders") derives the Metropolis case.

use super::Film;
use crate::image::{ImageBuf, Metadata};
use crate::sensor::ReconstructionFilter;
use std::path::Path;

/// The work behind a film, which sets how its splats are scaled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Work {
    /// A pixel integrator: every pixel holds `spp` samples, and splats (light tracing) are scaled by
    /// 1/spp, one light path per camera sample.
    Pixels { spp: u64 },
    /// Metropolis chains: the film's pixel sums hold the direct-illumination pass (weighted by its
    /// samples), its splats the chains' records, each weighing 1/f. They are scaled by
    /// b · pixels / mutations, with b = `b_sum / b_samples` estimated from independent samples (the
    /// seeding pass and large steps).
    Chains { mutations: u64, b_sum: f64, b_samples: u64 },
}

impl Work {
    /// The factor the film's splat sums are resolved with.
    pub fn splat_scale(&self, pixels: usize) -> f64 {
        match *self {
            Work::Pixels { spp } => match spp {
                0 => 0.0,
                n => 1.0 / n as f64,
            },
            Work::Chains { mutations, b_sum, b_samples } => {
                if mutations == 0 || b_samples == 0 {
                    0.0
                } else {
                    b_sum / b_samples as f64 * pixels as f64 / mutations as f64
                }
            }
        }
    }

    /// The work of two renders together; both must be of the same kind.
    pub fn add(&self, other: &Work) -> Result<Work, String> {
        match (*self, *other) {
            (Work::Pixels { spp: a }, Work::Pixels { spp: b }) => Ok(Work::Pixels { spp: a + b }),
            (
                Work::Chains { mutations: m1, b_sum: s1, b_samples: n1 },
                Work::Chains { mutations: m2, b_sum: s2, b_samples: n2 },
            ) => Ok(Work::Chains { mutations: m1 + m2, b_sum: s1 + s2, b_samples: n1 + n2 }),
            _ => Err("a pixel integrator's render cannot be merged with a Metropolis one".into()),
        }
    }

    fn kind(&self) -> &'static str {
        match self {
            Work::Pixels { .. } => "pixels",
            Work::Chains { .. } => "chains",
        }
    }
}

/// A film and its work.
#[derive(Clone, Debug)]
pub struct RenderState {
    pub film: Film,
    pub work: Work,
}

/// Names of the EXR parts a state file adds beside the image: the pixel means (camera samples or the
/// direct pass) and the unscaled splat sums.
pub const MEAN_LAYER: &str = "hslt.mean";
pub const SPLAT_LAYER: &str = "hslt.splats";

/// Metadata key prefix of a state file's work.
const KEY: &str = "hslt.state.";

impl RenderState {
    pub fn new(film: Film, work: Work) -> RenderState {
        let mut state = RenderState { film, work };
        state.rescale();
        state
    }

    fn rescale(&mut self) {
        self.film.splat_scale = self.work.splat_scale(self.film.width * self.film.height);
    }

    /// Adds another render of the same scene and integrator: exactly one render of both renders' work
    /// for pixel integrators whose sample indices do not overlap; for Metropolis the chains of both
    /// with b pooled over both renders' independent samples.
    pub fn absorb(&mut self, other: &RenderState) -> Result<(), String> {
        if (self.film.width, self.film.height) != (other.film.width, other.film.height) {
            return Err(format!(
                "the images are {}x{} and {}x{}",
                self.film.width, self.film.height, other.film.width, other.film.height
            ));
        }
        self.work = self.work.add(&other.work)?;
        self.film.merge(&other.film);
        self.rescale();
        Ok(())
    }

    pub fn image(&self) -> ImageBuf {
        self.film.to_image()
    }

    /// The extra EXR parts that hold the film's sums (written after the image itself).
    pub fn layers(&self) -> Vec<(&'static str, ImageBuf)> {
        vec![(MEAN_LAYER, self.film.mean_image()), (SPLAT_LAYER, self.film.splat_sum_image())]
    }

    /// The work as metadata (`hslt.state.*`), with the per-pixel sample count of the means. The film
    /// must have the same count in every pixel, which whole passes give (`render::render`).
    pub fn metadata(&self) -> Result<Metadata, String> {
        let count = self.film.uniform_count().ok_or("the film's pixels hold different sample counts")?;
        let mut meta: Metadata = vec![
            (format!("{KEY}kind"), self.work.kind().into()),
            (format!("{KEY}pixel_samples"), count.to_string()),
        ];
        match self.work {
            Work::Pixels { spp } => meta.push((format!("{KEY}spp"), spp.to_string())),
            Work::Chains { mutations, b_sum, b_samples } => {
                meta.push((format!("{KEY}mutations"), mutations.to_string()));
                // Rust prints the shortest string that reads back as the same f64.
                meta.push((format!("{KEY}b_sum"), format!("{b_sum:e}")));
                meta.push((format!("{KEY}b_samples"), b_samples.to_string()));
            }
        }
        Ok(meta)
    }

    /// Reads a state written as an EXR with `layers` and `metadata` (a part or a checkpoint).
    pub fn read(path: &Path, rfilter: ReconstructionFilter) -> anyhow::Result<RenderState> {
        let name = path.display();
        let meta = crate::image::read_exr_metadata(path)?;
        let get = |key: &str| -> anyhow::Result<&str> {
            let full = format!("{KEY}{key}");
            meta.iter().find(|(k, _)| *k == full).map(|(_, v)| v.as_str()).ok_or_else(|| {
                anyhow::anyhow!(
                    "{name}: no {full} in its metadata (expected an EXR written by `hslt render --part` or \
                     --checkpoint, or by `hslt merge`)"
                )
            })
        };
        let integer = |key: &str| -> anyhow::Result<u64> {
            let v = get(key)?;
            v.parse().map_err(|_| anyhow::anyhow!("{name}: {KEY}{key} = {v:?} (expected a count)"))
        };
        let work = match get("kind")? {
            "pixels" => Work::Pixels { spp: integer("spp")? },
            "chains" => {
                let v = get("b_sum")?;
                let b_sum =
                    v.parse::<f64>().ok().filter(|x| x.is_finite() && *x >= 0.0).ok_or_else(|| {
                        anyhow::anyhow!("{name}: {KEY}b_sum = {v:?} (expected a non-negative number)")
                    })?;
                Work::Chains { mutations: integer("mutations")?, b_sum, b_samples: integer("b_samples")? }
            }
            other => anyhow::bail!("{name}: {KEY}kind = {other:?} (expected \"pixels\" or \"chains\")"),
        };
        let count = integer("pixel_samples")?;
        let layers = crate::image::read_exr_layers(path)?;
        let layer = |wanted: &str| -> anyhow::Result<&ImageBuf> {
            layers.iter().find(|(n, _)| n == wanted).map(|(_, img)| img).ok_or_else(|| {
                anyhow::anyhow!("{name}: no EXR part named {wanted:?} (the sums a merge or --resume needs)")
            })
        };
        let (mean, splats) = (layer(MEAN_LAYER)?, layer(SPLAT_LAYER)?);
        if (mean.width, mean.height) != (splats.width, splats.height)
            || mean.channels < 3
            || splats.channels < 3
        {
            anyhow::bail!("{name}: the parts {MEAN_LAYER} and {SPLAT_LAYER} differ in size or lack RGB");
        }
        let mut film = Film::with_filter(mean.width, mean.height, rfilter);
        film.add_image_as_samples(mean, count);
        film.add_splat_image(splats);
        Ok(RenderState::new(film, work))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Splat;
    use crate::spectrum::Spectrum;
    use glam::Vec2;

    fn pixel_state(values: [f32; 2], spp: u64, splat: f32) -> RenderState {
        let mut film = Film::new(2, 1);
        let mut img = ImageBuf::new(2, 1, 3);
        img.data = vec![values[0]; 3].into_iter().chain(vec![values[1]; 3]).collect();
        film.add_image_as_samples(&img, spp);
        film.add_splat(&Splat { pos: Vec2::new(0.5, 0.5), value: Spectrum::splat(splat), layer: None });
        RenderState::new(film, Work::Pixels { spp })
    }

    #[test]
    fn pixel_states_merge_to_the_sample_weighted_mean_with_splats_over_all_samples() {
        let mut a = pixel_state([1.0, 2.0], 1, 4.0);
        let b = pixel_state([4.0, 8.0], 3, 8.0);
        a.absorb(&b).unwrap();
        let img = a.image();
        // (1·1 + 4·3)/4 + (4 + 8)/4, and (2·1 + 8·3)/4.
        assert_eq!(img.data[0], 13.0 / 4.0 + 3.0);
        assert_eq!(img.data[3], 26.0 / 4.0);
        assert_eq!(a.work, Work::Pixels { spp: 4 });
    }

    #[test]
    fn chain_states_pool_b_over_their_independent_samples() {
        let state = |b_sum: f64, b_samples: u64, mutations: u64, splat: f32| {
            let mut film = Film::new(1, 1);
            film.add_splat(&Splat { pos: Vec2::new(0.5, 0.5), value: Spectrum::splat(splat), layer: None });
            RenderState::new(film, Work::Chains { mutations, b_sum, b_samples })
        };
        let mut a = state(10.0, 10, 100, 50.0);
        assert_eq!(a.image().data[0], 1.0 * 50.0 / 100.0);
        a.absorb(&state(30.0, 10, 300, 90.0)).unwrap();
        // b = 40/20, splats (50 + 90) over 400 mutations.
        assert_eq!(a.image().data[0], (2.0 * 140.0 / 400.0) as f32);
        assert!(a.absorb(&pixel_state([0.0, 0.0], 1, 0.0)).is_err());
    }

    #[test]
    fn a_state_file_reads_back_as_the_same_image() {
        let dir = std::env::temp_dir().join(format!("hslt-state-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.exr");
        let state = pixel_state([0.5, 0.25], 7, 3.0);
        let mut meta = state.metadata().unwrap();
        meta.push(("hslt.integrator".into(), "bdpt".into()));
        let layers = state.layers();
        let image = state.image();
        let mut parts: Vec<(&str, &ImageBuf)> = vec![("combined", &image)];
        parts.extend(layers.iter().map(|(n, img)| (*n, img)));
        crate::image::write_exr_layers(&path, &parts, &meta).unwrap();
        let back = RenderState::read(&path, ReconstructionFilter::Box).unwrap();
        assert_eq!(back.work, state.work);
        assert_eq!(back.image().data, state.image().data);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
