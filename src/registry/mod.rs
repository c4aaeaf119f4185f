//! The integrator registry: technique names (CLI and scene files) to configured integrators, and
//! each path-space technique's default mutation mixture. It sits above both the pixel integrators
//! (`integrators`) and the Metropolis methods (`metropolis`) so neither has to import the other to dispatch.

use crate::integrators::{Bdpt, PathTracer};
use crate::metropolis::{MltSettings, MutationKind, MutationSettings, PathMlt};
use crate::render::{DepthLimits, Integrator, TiledRenderer};

/// The integrators the CLI can select.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntegratorKind {
    Path,
    Bdpt,
    Pssmlt,
    /// Veach's path-space MLT.
    Mlt,
    /// Manifold exploration MLT.
    Memlt,
    /// HSLT with the bidirectional mutation.
    Hslt,
    /// HSLT with the full MLT mutation set.
    HsltMlt,
}

impl IntegratorKind {
    /// Parses a CLI or scene-file name (`pt` and Mitsuba's `path` are the same).
    pub fn parse(name: &str) -> Result<IntegratorKind, String> {
        let kind = match name {
            "pt" | "path" => IntegratorKind::Path,
            "bdpt" => IntegratorKind::Bdpt,
            "pssmlt" => IntegratorKind::Pssmlt,
            "mlt" => IntegratorKind::Mlt,
            "memlt" => IntegratorKind::Memlt,
            "hslt" => IntegratorKind::Hslt,
            "hslt+mlt" => IntegratorKind::HsltMlt,
            other => {
                return Err(format!(
                    "unknown integrator '{other}' (available: {})",
                    IntegratorKind::available_names()
                ))
            }
        };
        if !kind.available() {
            return Err(format!(
                "integrator '{name}' is not available in this build yet (available: {})",
                IntegratorKind::available_names()
            ));
        }
        Ok(kind)
    }

    /// Every integrator, in the order reports list them.
    pub const ALL: [IntegratorKind; 7] = [
        IntegratorKind::Path,
        IntegratorKind::Bdpt,
        IntegratorKind::Pssmlt,
        IntegratorKind::Mlt,
        IntegratorKind::Memlt,
        IntegratorKind::Hslt,
        IntegratorKind::HsltMlt,
    ];

    /// The integrators this build implements (path-space ones need all their default mutations).
    pub fn available_kinds() -> Vec<IntegratorKind> {
        IntegratorKind::ALL.into_iter().filter(|k| k.available()).collect()
    }

    pub fn available(self) -> bool {
        self.default_mutations().iter().all(|(m, _)| m.available())
    }

    /// Names `parse` accepts, for messages.
    pub fn available_names() -> String {
        IntegratorKind::available_kinds().iter().map(|k| k.name()).collect::<Vec<_>>().join(", ")
    }

    pub fn name(self) -> &'static str {
        match self {
            IntegratorKind::Path => "pt",
            IntegratorKind::Bdpt => "bdpt",
            IntegratorKind::Pssmlt => "pssmlt",
            IntegratorKind::Mlt => "mlt",
            IntegratorKind::Memlt => "memlt",
            IntegratorKind::Hslt => "hslt",
            IntegratorKind::HsltMlt => "hslt+mlt",
        }
    }

    /// Whether this is a path-space Metropolis method (configured by a mutation mixture).
    pub fn is_path_space(self) -> bool {
        !self.default_mutations().is_empty()
    }

    /// The mutation mixture of a path-space technique (empty for the others): Veach's set for MLT,
    /// plus the manifold perturbation for MEMLT (Mitsuba's MEMLT mixture), the half-vector mutation
    /// with the bidirectional one for HSLT (the paper's "HSLT"), and with Veach's set for HSLT+MLT.
    /// Every mixture has the large step (and with it the direct pass runs,
    /// `DirectPass::for_path_space`). The HSLT mixtures add the half-vector lens and caustic
    /// perturbations (HSLT's parameterisation in Veach's two perturbations; the caustic one halved
    /// the chains' error on the rings' floor caustics, docs/mlt-sessions.md, session 14) and give the
    /// half-vector mutation a tenth of the proposals: one cost about as much time as 50 lens
    /// perturbations (jewelry's rings, 2 threads), so at weight 1 it took 90% of the time and the
    /// rings' relative MSE was 2.2× that at 0.1 (docs/mlt-sessions.md, session 8). At 18 lens
    /// perturbations' cost (session 15) weight 1 still loses on rings and jewelry. The large step
    /// makes `LARGE_STEP_SHARE` of the proposals.
    pub fn default_mutations(self) -> Vec<(MutationKind, f64)> {
        use MutationKind::*;
        let veach = [(Bidirectional, 1.0), (Lens, 1.0), (Caustic, 1.0), (MultiChain, 1.0)];
        let half_vector = [(HalfVector, HALF_VECTOR_WEIGHT), (HalfVectorLens, 1.0), (HalfVectorCaustic, 1.0)];
        let mut mixture = match self {
            IntegratorKind::Path | IntegratorKind::Bdpt | IntegratorKind::Pssmlt => return Vec::new(),
            IntegratorKind::Mlt => veach.to_vec(),
            IntegratorKind::Memlt => [&veach[..], &[(Manifold, 1.0)]].concat(),
            IntegratorKind::Hslt => [&[(Bidirectional, 1.0)], &half_vector[..]].concat(),
            IntegratorKind::HsltMlt => [&veach[..], &half_vector[..]].concat(),
        };
        let others: f64 = mixture.iter().map(|(_, w)| w).sum();
        // Rounded so the metadata's mixture reads 6.1, not 6.1000000000000005.
        let large = (others * LARGE_STEP_SHARE / (1.0 - LARGE_STEP_SHARE) * 1e6).round() / 1e6;
        mixture.push((LargeStep, large));
        mixture
    }
}

/// The share of the default path-space mixtures' proposals that are large steps. An accepted large
/// step is a chain's only jump across the image and between families of paths, and only about 0.45%
/// of them are accepted on the rings scene, so at weight 1 (a sixth of HSLT+MLT's proposals) a chain
/// (of 128) made about 700 such jumps in 60 s where a PSSMLT chain (of 64) made 5 000, and the
/// chains' image had 3–5× PSSMLT's error on 8×8 blocks. Half of the proposals lowered HSLT+MLT's
/// relative MSE on the rings' indirect light by a fifth, 1.61e-4 to 1.25e-4 (37%: 1.41e-4, 70%:
/// 1.45e-4), and did no harm on jewelry (docs/mlt-sessions.md, session 13).
pub const LARGE_STEP_SHARE: f64 = 0.5;

/// The half-vector mutation's weight in the default HSLT mixtures (the others' weights are 1).
pub const HALF_VECTOR_WEIGHT: f64 = 0.1;

/// Everything that configures an integrator, from the scene's `<integrator>` and the command line.
#[derive(Clone, Debug)]
pub struct IntegratorSettings {
    pub limits: DepthLimits,
    pub hide_emitters: bool,
    /// Shortest path rendered, in segments as `max_depth` counts them: 1 renders everything, 2 leaves
    /// out the emitters seen directly (`hide_emitters`), 3 renders indirect light only, which is what
    /// the Metropolis methods' chains render beside their direct pass (`metropolis::direct`), so an
    /// equal-time comparison at 3 measures the chains alone. Tungsten calls it `min_bounces`.
    pub min_depth: i32,
    /// BDPT: write per-strategy layers for path depths up to this.
    pub bdpt_strategies: Option<u32>,
    /// BDPT: MIS heuristic.
    pub mis: crate::path::MisHeuristic,
    /// PSSMLT: seeding pass size, chain count, large-step probability, target function. Path-space
    /// methods share its seeding pass size (when set) and target.
    pub pssmlt: crate::metropolis::PssmltSettings,
    /// Path-space methods: the number of chains (`None`: `metropolis::mlt::DEFAULT_PATH_CHAINS`).
    pub path_chains: Option<usize>,
    /// Path-space methods: mutations of a chain between restarts (`None`:
    /// `metropolis::mlt::DEFAULT_RESTART_EVERY`; 0 never restarts).
    pub restart_every: Option<u64>,
    /// Path-space methods: the share of a time limit the seeding pass runs for (`None`:
    /// `metropolis::mlt::SEED_TIME_SHARE`).
    pub seed_share: Option<f64>,
    /// Path-space methods: the mutation mixture (`None`: the technique's default) and the parameters
    /// of the individual mutations.
    pub mutations: Option<Vec<(MutationKind, f64)>>,
    pub mutation: MutationSettings,
}

impl IntegratorSettings {
    pub fn new(limits: DepthLimits, hide_emitters: bool) -> IntegratorSettings {
        IntegratorSettings {
            limits,
            hide_emitters,
            min_depth: 1,
            bdpt_strategies: None,
            mis: crate::path::MisHeuristic::Power,
            pssmlt: crate::metropolis::PssmltSettings::default(),
            path_chains: None,
            restart_every: None,
            seed_share: None,
            mutations: None,
            mutation: MutationSettings::default(),
        }
    }
}

/// Builds an integrator with default settings besides the depth limits.
pub fn make(kind: IntegratorKind, limits: DepthLimits, hide_emitters: bool) -> Box<dyn Integrator> {
    make_with(kind, &IntegratorSettings::new(limits, hide_emitters))
}

/// Builds an integrator.
pub fn make_with(kind: IntegratorKind, settings: &IntegratorSettings) -> Box<dyn Integrator> {
    let limits = settings.limits;
    let min_depth = settings.min_depth.max(1);
    // A path of one segment is an emitter seen directly: leaving those out is what hide_emitters does.
    let hide_emitters = settings.hide_emitters || min_depth >= 2;
    let bdpt = || {
        let mut bdpt = Bdpt::new(limits, hide_emitters);
        bdpt.heuristic = settings.mis;
        bdpt.min_path_vertices = min_depth as usize + 1;
        bdpt
    };
    // Nothing is left for a separate direct pass once the paths it renders (up to two segments,
    // `direct::CHAIN_MIN_VERTICES`) are left out: the chains get the whole time.
    let direct = if min_depth as usize + 1 >= crate::metropolis::direct::CHAIN_MIN_VERTICES {
        crate::metropolis::direct::DirectPass::Off
    } else {
        settings.pssmlt.direct
    };
    match kind {
        IntegratorKind::Path => {
            Box::new(TiledRenderer(Box::new(PathTracer { limits, hide_emitters, min_depth })))
        }
        IntegratorKind::Bdpt => {
            let mut bdpt = bdpt();
            bdpt.strategy_layers = settings.bdpt_strategies;
            Box::new(TiledRenderer(Box::new(bdpt)))
        }
        IntegratorKind::Pssmlt => {
            let pssmlt = crate::metropolis::PssmltSettings { direct, ..settings.pssmlt.clone() };
            Box::new(crate::metropolis::Pssmlt::new(bdpt(), pssmlt))
        }
        IntegratorKind::Mlt | IntegratorKind::Memlt | IntegratorKind::Hslt | IntegratorKind::HsltMlt => {
            let mut mlt = MltSettings::for_technique(
                settings.mutations.clone().unwrap_or_else(|| kind.default_mutations()),
            );
            mlt.seed_paths = settings.pssmlt.seed_paths;
            mlt.seed_share = settings.seed_share.unwrap_or(crate::metropolis::mlt::SEED_TIME_SHARE);
            mlt.direct = direct;
            mlt.chains = settings.path_chains.unwrap_or(crate::metropolis::mlt::DEFAULT_PATH_CHAINS);
            mlt.restart_every =
                settings.restart_every.unwrap_or(crate::metropolis::mlt::DEFAULT_RESTART_EVERY);
            mlt.target = settings.pssmlt.target;
            mlt.mutation = settings.mutation.clone();
            Box::new(PathMlt::new(kind.name(), bdpt(), mlt))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_mixtures_give_the_large_step_its_share_and_read_back_from_their_metadata() {
        for kind in IntegratorKind::ALL.into_iter().filter(|k| k.is_path_space()) {
            let mixture = kind.default_mutations();
            let total: f64 = mixture.iter().map(|(_, w)| w).sum();
            let large: f64 =
                mixture.iter().filter(|(m, _)| *m == MutationKind::LargeStep).map(|(_, w)| w).sum();
            assert!(
                (large / total - LARGE_STEP_SHARE).abs() < 1e-6,
                "{}: large-step share {}",
                kind.name(),
                large / total
            );
            // The render's `hslt.mlt.mutation_set` metadata prints the mixture as --mutations reads it.
            let printed: Vec<String> = mixture.iter().map(|(m, w)| format!("{}:{w}", m.name())).collect();
            let printed = printed.join(",");
            assert!(!printed.contains("0000"), "{}: {printed}", kind.name());
            assert_eq!(MutationKind::parse_mixture(&printed).unwrap(), mixture, "{}", kind.name());
        }
    }
}
