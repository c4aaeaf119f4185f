//! Cases 1–8 of the HSLT digest §5, the geometric extremes of the half-vector machinery: near-specular
//! and very rough lobes, grazing half vectors, long chains, near-singular Jacobians (a ball lens's
//! focus), Newton divergence at total internal reflection, tangent-frame seams and flat shading.

mod chains;
mod frames;
mod lens;
mod roughness;
mod support;

use super::Case;

pub fn cases() -> Vec<Case> {
    vec![
        Case {
            number: 1,
            name: "near-specular roughness",
            expected:
                "tiny lobes sampled in f64 with their exact spread, steps floored at 1e-8, step shares ∝ α \
                       (Fig. 17), finite chains down to α = 1e-4",
            run: roughness::near_specular,
        },
        Case {
            number: 2,
            name: "very rough vertices",
            expected: "Phong exponent clamped at 0 (whole-disk lobe) and detailed balance with α ≥ 1",
            run: roughness::very_rough,
        },
        Case {
            number: 3,
            name: "grazing configurations",
            expected:
                "kernel finite within 1e-12 of the rim; finite det J and T (f64) and NaN-free chains with \
                 half vectors closer than 1e-3 to the rim",
            run: roughness::grazing,
        },
        Case {
            number: 4,
            name: "long chains",
            expected:
                "no-pivot block LU as accurate as pivoted dense LU for k = 10…20, Newton capped, every \
                       built proposal confirmed reversible, no NaN",
            run: chains::long_chains,
        },
        Case {
            number: 5,
            name: "near-singular J (ball-lens focus)",
            expected:
                "det J folds at the paraxial focus; walks there fail or meet their targets (never clamped); \
                       the singularity test is relative (same verdicts at 1e-3 and 1e3 scale)",
            run: lens::lens_focus,
        },
        Case {
            number: 6,
            name: "Newton divergence (TIR slab)",
            expected:
                "refraction past the critical angle fails cleanly with a reason; every converged walk is \
                       the requested refraction; iterations capped",
            run: lens::tir_slab,
        },
        Case {
            number: 7,
            name: "tangent-frame discontinuities",
            expected:
                "a rotated (u, v) parameterisation gives the same proposals from the same random numbers and \
                 the same image; no-UV meshes the same acceptance; walks at a sphere's uv pole and across the \
                 frame field's switch as good as on its equator, with detailed balance across the switch",
            run: frames::frame_rotation,
        },
        Case {
            number: 8,
            name: "flat-shaded geometry",
            expected: "walks fail more on flat facets, as counted rejections: no NaN, detailed balance holds",
            run: frames::flat_shading,
        },
    ]
}
