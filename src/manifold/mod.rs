//! The manifold machinery shared by HSLT (Kaplanyan et al. 2014) and manifold exploration MLT (Jakob and
//! Marschner 2012): half-vector constraints of a path with fixed endpoints, their block-tridiagonal
//! Jacobian and its solvers, and the Möbius-shifted half-vector proposals.

pub mod blocktri;
pub mod constraint;
pub mod corrector;
pub mod sampling;
pub mod sweep;
pub mod trace;
pub mod walk;

pub use blocktri::{invert_block, BlockLu, BlockTridiagonal, LogDet, Singular};
pub use constraint::{
    frame_chart, half_vector, half_vector_constraint, normal_frame_reference, path_constraints, path_etas,
    path_geometry, path_geometry_in_chart, path_half_vectors, ConstraintError, LocalGeometry,
    PathConstraints, VertexConstraint,
};
pub use corrector::{corrector_pass, corrector_pass_counting_rays, CorrectorFailure};
pub use sampling::{
    bandwidth_shares, beckmann_to_phong, mobius, mobius_inverse, step_sizes, HalfVectorProposal,
    PhongDiskLobe, StepSizes,
};
pub use trace::{direction_per_half_vector, log_dirac_factor, scatter_with_half_vector};
pub use walk::{
    walk, walk_counting_rays, walk_in_chart_counting_rays, walk_many, walk_many_through, WalkError, WalkJob,
    WalkResult, WalkSettings, WalkStart,
};
