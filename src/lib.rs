//! hslt: a light-transport renderer built around Half-vector Space Light Transport
//! (Kaplanyan, Hanika, Dachsbacher 2014) inside path-space Metropolis light transport.

// `!(x > 0.0)` is how this renderer rejects NaN together with non-positive values; rewriting it as
// `x <= 0.0` would let NaN through, so the lint that asks for that is off.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accel;
pub mod bench;
pub mod bsdf;
pub mod cli;
pub mod fuzzing;
pub mod geometry;
pub mod image;
pub mod integrators;
pub mod lights;
pub mod manifold;
pub mod metropolis;
pub mod path;
pub mod props;
pub mod registry;
pub mod render;
pub mod report;
pub mod resources;
pub mod sampling;
pub mod scene;
pub mod sensor;
pub mod spectrum;
pub mod stability;
pub mod texture;
