//! Metropolis light transport: a generic Metropolis–Hastings chain with pluggable mutations (Veach &
//! Guibas 1997; Veach 1997, ch. 11) and primary-sample-space MLT over BDPT (Kelemen et al. 2002).
//! Path-space mutations (bidirectional, lens, caustic, multi-chain, HSLT) implement `chain::Mutation`.

pub mod chain;
pub mod direct;
pub mod driver;
pub mod mlt;
pub mod mutations;
pub mod normalization;
pub mod path_state;
pub mod pss;
pub mod pssmlt;
pub mod seeds;

pub use chain::{
    Chain, ChainState, Failure, Mutation, MutationStats, Proposal, TargetFunction, WeightedMutation,
};
pub use mlt::{MltSettings, PathMlt, PathSeeds};
pub use mutations::{ManifoldPerturbation, MutationKind, MutationSettings};
pub use path_state::{PathContext, PathState};
pub use pss::PssSampler;
pub use pssmlt::{PssSample, Pssmlt, PssmltSettings};
