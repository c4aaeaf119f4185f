//! Path-space mutations, one file each (Veach & Guibas 1997; Jakob & Marschner 2012; Kaplanyan et al.
//! 2014): each implements `chain::Mutation<PathState, PathContext>` and returns the ratio of transition
//! densities T(y→x)/T(x→y) in the measure of `PathState::contribution` (product area measure with the
//! Dirac deltas of specular vertices cancelled, see `Vertex::dirac_lobe`).

pub mod bidir;
pub mod caustic;
pub mod halfvector;
pub mod hvcaustic;
pub mod hvlens;
pub mod largestep;
pub mod lens;
mod manifold;
pub mod multichain;
pub mod perturb;
pub mod subchain;

pub use manifold::ManifoldPerturbation;

use super::chain::Mutation;
use super::path_state::{PathContext, PathState};
use crate::scene::Scene;

/// The mutations a path-space chain can mix.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MutationKind {
    /// Veach's bidirectional mutation: delete a sub-path, regenerate it from both sides.
    Bidirectional,
    /// Lens perturbation: move the image point, follow the specular chain from the camera.
    Lens,
    /// Caustic perturbation: move the direction at the light side of a specular chain seen by the camera.
    Caustic,
    /// Multi-chain perturbation: lens perturbation continued through several specular chains.
    MultiChain,
    /// Manifold perturbation (MEMLT, Jakob & Marschner 2012).
    Manifold,
    /// Half-vector space mutation (HSLT, Kaplanyan et al. 2014).
    HalfVector,
    /// Large step: an independent new path from the bidirectional sampler.
    LargeStep,
    /// Lens perturbation continued through near-specular glossy vertices at fixed half vectors.
    HalfVectorLens,
    /// Caustic perturbation continued through near-specular glossy vertices at fixed half vectors.
    HalfVectorCaustic,
}

impl MutationKind {
    pub const ALL: [MutationKind; 9] = [
        MutationKind::Bidirectional,
        MutationKind::Lens,
        MutationKind::Caustic,
        MutationKind::MultiChain,
        MutationKind::Manifold,
        MutationKind::HalfVector,
        MutationKind::LargeStep,
        MutationKind::HalfVectorLens,
        MutationKind::HalfVectorCaustic,
    ];

    pub fn name(self) -> &'static str {
        match self {
            MutationKind::Bidirectional => "bidir",
            MutationKind::Lens => "lens",
            MutationKind::Caustic => "caustic",
            MutationKind::MultiChain => "multichain",
            MutationKind::Manifold => "manifold",
            MutationKind::HalfVector => "hslt",
            MutationKind::LargeStep => "largestep",
            MutationKind::HalfVectorLens => "hvlens",
            MutationKind::HalfVectorCaustic => "hvcaustic",
        }
    }

    pub fn parse(name: &str) -> Result<MutationKind, String> {
        MutationKind::ALL.into_iter().find(|k| k.name() == name).ok_or_else(|| {
            let names: Vec<&str> = MutationKind::ALL.iter().map(|k| k.name()).collect();
            format!("unknown mutation '{name}' (known: {})", names.join(", "))
        })
    }

    /// Parses a mixture such as `bidir:1,lens:0.5,caustic` (a missing weight is 1).
    pub fn parse_mixture(text: &str) -> Result<Vec<(MutationKind, f64)>, String> {
        let mut out = Vec::new();
        for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (name, weight) = match item.split_once(':') {
                Some((n, w)) => {
                    let w: f64 = w
                        .trim()
                        .parse()
                        .map_err(|_| format!("mutation weight '{w}' in '{item}' is not a number"))?;
                    (n.trim(), w)
                }
                None => (item, 1.0),
            };
            if !(weight.is_finite() && weight >= 0.0) {
                return Err(format!("mutation weight in '{item}' must be a finite number ≥ 0"));
            }
            let kind = MutationKind::parse(name)?;
            if out.iter().any(|(k, _)| *k == kind) {
                return Err(format!("mutation '{name}' is listed twice"));
            }
            out.push((kind, weight));
        }
        if !out.iter().any(|(_, w)| *w > 0.0) {
            return Err(format!("the mutation list '{text}' has no mutation with a positive weight"));
        }
        Ok(out)
    }

    /// Whether this build implements the mutation.
    pub fn available(self) -> bool {
        // Every mutation is implemented; kept so a future one can land before it works.
        MutationKind::ALL.contains(&self)
    }
}

/// Parameters of the individual mutations (each mutation's file documents its own).
#[derive(Clone, Debug, PartialEq)]
pub struct MutationSettings {
    /// MEMLT's perturbation size λ (Jakob & Marschner 2012; the HSLT paper's Figure 16 uses 50).
    pub lambda: f64,
    /// MEMLT: glossy vertices with roughness α below this are held at their half vector like specular
    /// ones (Jakob & Marschner's treatment of near-specular surfaces).
    pub specular_threshold: f32,
    /// HSLT's half-vector mutation: step scale, stratification, image step and walk constants.
    pub halfvector: halfvector::HalfVectorParams,
    /// The large step's distribution of lengths and splits (set from the seeding pass by `PathMlt`).
    pub large_step_strategies: largestep::StrategyPmf,
}

impl Default for MutationSettings {
    fn default() -> MutationSettings {
        MutationSettings {
            lambda: 50.0,
            specular_threshold: 0.1,
            halfvector: halfvector::HalfVectorParams::default(),
            large_step_strategies: largestep::StrategyPmf::default(),
        }
    }
}

/// Builds a mutation; `None` if this build does not implement it (`MutationKind::available`; the CLI
/// refuses such mixtures with a message before rendering).
pub fn make<'a>(
    kind: MutationKind,
    settings: &MutationSettings,
    _scene: &Scene,
) -> Option<Box<dyn Mutation<PathState, PathContext<'a>>>> {
    match kind {
        MutationKind::Bidirectional => Some(Box::new(bidir::BidirectionalMutation)),
        MutationKind::Lens => Some(Box::new(lens::LensPerturbation)),
        MutationKind::Caustic => Some(Box::new(caustic::CausticPerturbation)),
        MutationKind::MultiChain => Some(Box::new(multichain::MultiChainPerturbation)),
        MutationKind::HalfVector => Some(Box::new(halfvector::HalfVectorMutation::new(settings.halfvector))),
        MutationKind::LargeStep => {
            Some(Box::new(largestep::LargeStep { strategies: settings.large_step_strategies.clone() }))
        }
        MutationKind::HalfVectorLens => {
            Some(Box::new(hvlens::HalfVectorLensPerturbation { threshold: settings.specular_threshold }))
        }
        MutationKind::HalfVectorCaustic => Some(Box::new(hvcaustic::HalfVectorCausticPerturbation {
            threshold: settings.specular_threshold,
        })),
        MutationKind::Manifold => {
            Some(Box::new(ManifoldPerturbation::new(settings.lambda, settings.specular_threshold)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mixtures_parse_with_default_weights_and_reject_bad_input() {
        let m = MutationKind::parse_mixture("bidir:1,lens:0.5, caustic").unwrap();
        assert_eq!(
            m,
            vec![(MutationKind::Bidirectional, 1.0), (MutationKind::Lens, 0.5), (MutationKind::Caustic, 1.0)]
        );
        assert!(MutationKind::parse_mixture("bidir:x").unwrap_err().contains("not a number"));
        assert!(MutationKind::parse_mixture("warp:1").unwrap_err().contains("unknown mutation 'warp'"));
        assert!(MutationKind::parse_mixture("lens:0").unwrap_err().contains("positive weight"));
        assert!(MutationKind::parse_mixture("lens,lens").unwrap_err().contains("twice"));
        assert!(MutationKind::parse_mixture("lens:-1").is_err());
    }
}
