//! The pixel integrators, one file each (pbrt-v4's separation of integrators from materials and
//! samplers): they implement `render::PixelIntegrator`, and the render loop in `render` drives them over
//! the film, so every integrator gets progress, time budgets and interruption for free. The Metropolis
//! methods live in `metropolis`; `registry` builds either kind by name.

pub mod aov;
pub mod bdpt;
mod path;

pub use bdpt::Bdpt;
pub use path::PathTracer;
