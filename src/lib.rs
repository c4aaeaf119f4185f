//! hslt: a light-transport renderer built around Half-vector Space Light Transport
//! (Kaplanyan, Hanika, Dachsbacher 2014) inside path-space Metropolis light transport.

pub mod accel;
pub mod bsdf;
pub mod geometry;
pub mod image;
pub mod sampling;
pub mod scene;
pub mod spectrum;
pub mod texture;
