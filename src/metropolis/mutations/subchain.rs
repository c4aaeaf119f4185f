//! The stretch of a path the half-vector mutation moves (improved HSLT, Hanika, Kaplanyan and
//! Dachsbacher 2015; digest 2.11): a chain x_b … x_c between two anchor vertices, held while the
//! vertices between them walk, chosen with rough ends and short chains preferred.

use crate::path::{ScatterClass, Vertex, VertexKind};

/// The stretch x_start … x_end of a path that one proposal moves: its inner vertices walk, its ends
/// and everything outside it stay where they are. The whole path is start 0, end k.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Chain {
    pub start: usize,
    pub end: usize,
}

/// Whether vertex `i` of `path` can hold a chain's end: the camera, an emitter with a position, or a
/// non-Dirac surface vertex (moving a Dirac vertex's neighbour breaks its specular constraint). The
/// weight is how little the vertex's own scattering changes when its neighbour moves: 1 for the
/// endpoints and diffuse vertices, the roughness α for glossy ones ([C13] weighs break-up vertices by
/// roughness).
fn anchor_weight(path: &[Vertex], i: usize) -> Option<f64> {
    let v = &path[i];
    if i == 0 {
        return (v.kind == VertexKind::Camera).then_some(1.0);
    }
    if i == path.len() - 1 {
        return (v.kind != VertexKind::InfiniteLight).then_some(1.0);
    }
    if v.kind != VertexKind::Surface || v.delta {
        return None;
    }
    match v.class {
        ScatterClass::Diffuse => Some(1.0),
        ScatterClass::Glossy { alpha } => Some((alpha as f64).min(1.0)),
        ScatterClass::Specular => None,
    }
}

/// Whether an inner vertex can walk: a surface vertex that scatters through a non-Dirac lobe
/// (perturbed) or is purely specular (Dirac, held at h = 0). `smooth` means the BSDF has a non-Dirac
/// lobe; a Dirac vertex must be purely specular, so that holding h = 0 keeps it on its only lobe.
pub(super) fn walkable(v: &Vertex) -> bool {
    v.kind == VertexKind::Surface && if v.delta { v.class == ScatterClass::Specular } else { v.smooth }
}

/// Every chain of `path` the sub-chain proposal may move, with its unnormalised weight: both ends
/// anchors (`anchor_weight`), every inner vertex walkable and at least one glossy non-Dirac one. The
/// weight is the product of the ends' weights, halved for every inner vertex beyond the first:
/// shorter chains converge more often and cost fewer rays per corrector pass ([C13] likewise
/// prefers short chains), and rough ends change the path's throughput least.
pub fn sub_chains(path: &[Vertex]) -> Vec<(Chain, f64)> {
    let n = path.len();
    let mut out = Vec::new();
    if n < 3 || path[0].kind != VertexKind::Camera {
        return out;
    }
    for start in 0..n - 2 {
        let Some(w_start) = anchor_weight(path, start) else { continue };
        let mut glossy = false;
        for end in start + 2..n {
            let v = &path[end - 1];
            if !walkable(v) {
                break;
            }
            glossy |= !v.delta && matches!(v.class, ScatterClass::Glossy { .. });
            let Some(w_end) = anchor_weight(path, end) else { continue };
            if glossy {
                let weight = w_start * w_end * 0.5f64.powi((end - start - 2) as i32);
                out.push((Chain { start, end }, weight));
            }
        }
    }
    out
}
