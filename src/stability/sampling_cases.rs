//! Stiff cases 9–15 of the HSLT method digest (§5): degenerate endpoints, index-matched interfaces, the
//! Möbius kernel, detailed balance, scale invariance, stuck chains and f32 against f64. Each submodule
//! builds its configuration, measures the robust behaviour and judges it; this file registers them and
//! holds what they share (the tiny glossy-plane scene, seeding, statistics).

mod balance;
mod endpoints;
mod index_matched;
mod kernel;
mod precision;
pub(crate) mod scale;
mod stuck;

use std::sync::atomic::AtomicBool;

use super::Case;
use crate::integrators::Bdpt;
use crate::metropolis::{MutationStats, PathSeeds, PathState};
use crate::render::DepthLimits;
use crate::scene::Scene;

pub fn cases() -> Vec<Case> {
    vec![
        Case {
            number: 9,
            name: "degenerate segments and endpoints",
            expected:
                "zero-length edges and x_{k-1} on x_k fail as counted rejections, never NaN; pinhole and \
                       point light stay pinned; environment endpoints are left to other mutations; a pixel \
                       outside the film is a rejection",
            run: endpoints::run,
        },
        Case {
            number: 10,
            name: "index-matched and null interfaces",
            expected: "unnormalised H~ with solution 0, per-vertex factor 1 in f_H, walks converge through \
                       them; such vertices get no step share",
            run: index_matched::run,
        },
        Case {
            number: 11,
            name: "Möbius and kernel validation",
            expected:
                "histogram of 10^7 kernel samples matches the pdf for centres of modulus 0, 0.5, 0.9, 0.999, the pdf \
                       carries unit mass, q_X(Y) > 0 wherever q_Y(X) > 0",
            run: kernel::run,
        },
        Case {
            number: 12,
            name: "detailed balance on a tiny scene",
            expected:
                "stationary histogram of h_1 follows f_H on a glossy plane with point light and pinhole; \
                       f(X)T(X→Y)a(X→Y) = f(Y)T(Y→X)a(Y→X) for random pairs",
            run: balance::run,
        },
        Case {
            number: 13,
            name: "scale invariance (1e-3, 1e3)",
            expected: "acceptance, failure shares and image flux unchanged when the scene is scaled",
            run: scale::run,
        },
        Case {
            number: 14,
            name: "stuck chains",
            expected: "rejection run lengths logged; a path HSLT cannot move is moved by the bidirectional \
                       mutation; no forced acceptance",
            run: stuck::run,
        },
        Case {
            number: 15,
            name: "f32 versus f64 A/B",
            expected: "same seed, same chains: no systematic difference in mean acceptance between det J in \
                       f32 and in f64",
            run: precision::run,
        },
    ]
}

/// The BDPT a scene's integrator settings describe: it seeds the chains and regrows paths.
fn bdpt_for(scene: &Scene) -> Bdpt {
    let limits = DepthLimits::of_scene(scene);
    Bdpt::new(limits, scene.integrator.hide_emitters)
}

fn seeding(scene: &Scene, bdpt: &Bdpt, seed: u64, paths: usize) -> PathSeeds {
    PathSeeds::run(scene, bdpt, seed, paths, &AtomicBool::new(false))
}

fn target(state: &PathState) -> f64 {
    state.luminance()
}

/// Mean and standard error of the mean (0 spread for fewer than two values).
fn mean_se(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    if values.len() < 2 {
        return (mean, 0.0);
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Mean and variance of the F(1, d) distribution, which t² of a mean over d + 1 independent runs
/// against its exact expectation follows.
fn f1_moments(d: f64) -> (f64, f64) {
    (d / (d - 2.0), 2.0 * d * d * (d - 1.0) / ((d - 2.0).powi(2) * (d - 4.0)))
}

/// Failure counts by reason, for the measure text.
fn failures(stats: &MutationStats) -> String {
    let parts: Vec<String> = stats.failed.iter().map(|(k, v)| format!("{k} {v}")).collect();
    if parts.is_empty() {
        "none".into()
    } else {
        parts.join(", ")
    }
}

/// A rough-conductor plane (Beckmann α, `plane_scale` times the unit square at z = 0) under a point
/// light, seen by a pinhole from above at an angle: every light path is camera → plane → light
/// (`max_depth` 2), so x_1 alone is free and its h_1 determines the path.
fn glossy_plane_xml(alpha: f64, plane_scale: f64, width: u32, height: u32) -> String {
    format!(
        r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="2" /></integrator>
  <sensor type="perspective">
    <float name="fov" value="50" />
    <transform name="to_world"><lookat origin="0, -4, 3" target="0, 0, 0" up="0, 0, 1" /></transform>
    <film type="hdrfilm"><integer name="width" value="{width}" /><integer name="height" value="{height}" /></film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="{plane_scale}" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="{alpha}" /></bsdf>
  </shape>
  <emitter type="point"><point name="position" x="0.3" y="1.2" z="1.5" /><rgb name="intensity" value="10, 10, 10" /></emitter>
</scene>"#
    )
}
