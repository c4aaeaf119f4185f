//! The corrector of the manifold walk (HSLT, Kaplanyan et al. 2014, Sec. 5.1; Jakob and Marschner 2012):
//! projects the predicted inner vertices of a path back onto the scene by ray casting, one inner vertex
//! after the other from x_0, then checks visibility to the fixed end x_k; several step fractions go at
//! once, and each row's rays are cast as one batched (Embree packet) query.

use glam::Vec3;

use super::constraint::ConstraintError;
use crate::accel::{Hit, RayQuery};
use crate::geometry::{offset_origin, Ray};
use crate::path::Vertex;
use crate::scene::{Scene, SurfaceInteraction};

/// Why one corrector pass at one step size was refused (the walk then halves the step).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CorrectorFailure {
    /// The ray towards vertex `vertex` hit nothing.
    Missed {
        vertex: usize,
    },
    /// It hit another shape than the one the vertex lies on.
    OtherShape {
        vertex: usize,
    },
    /// Reflection turned into transmission or back at `vertex`.
    ChangedSide {
        vertex: usize,
    },
    /// The last segment to the fixed end is blocked.
    Occluded,
    Constraint(ConstraintError),
}

/// Projects predicted positions back onto the scene for several step fractions at once: for each inner
/// vertex in turn, one batch of rays (one per live candidate) from the candidate's new previous vertex
/// through its predicted position, then one batch of visibility rays to the fixed end.
pub fn corrector_pass(
    scene: &Scene,
    current: &[Vertex],
    fractions: &[f64],
    predicted: impl Fn(usize, f64) -> Vec3,
) -> Vec<Result<Vec<Vertex>, CorrectorFailure>> {
    corrector_pass_counting_rays(scene, current, fractions, predicted, true, &mut 0)
}

/// `corrector_pass`, adding the rays it casts to `rays`; `batched` = false casts them one by one.
pub fn corrector_pass_counting_rays(
    scene: &Scene,
    current: &[Vertex],
    fractions: &[f64],
    predicted: impl Fn(usize, f64) -> Vec3,
    batched: bool,
    rays_cast: &mut u64,
) -> Vec<Result<Vec<Vertex>, CorrectorFailure>> {
    let mut pass = CorrectorPass::idle();
    pass.restart(current, fractions, true, predicted);
    let mut batch = RayBatch::default();
    while pass.is_running() {
        batch.clear();
        let slot = pass.emit(current, &mut batch);
        *rays_cast += slot.len as u64;
        batch.cast(scene.accel(), batched);
        pass.absorb(scene, current, &batch, &slot);
    }
    pass.built.into_iter().zip(pass.status).map(|(built, status)| status.map(|()| built)).collect()
}

/// One corrector pass in flight: one candidate path per step fraction, built vertex by vertex. Row i
/// (1 ≤ i < k) casts the rays that place vertex i, row k the visibility rays to the fixed end x_k.
pub(super) struct CorrectorPass {
    pub(super) fractions: Vec<f64>,
    /// `predicted[c * (k - 1) + i - 1]`: where candidate c's inner vertex i should land.
    predicted: Vec<Vec3>,
    /// Candidate c's vertices so far; only meaningful while `status[c]` is Ok. The buffers are reused
    /// from pass to pass, so a walk allocates them once.
    pub(super) built: Vec<Vec<Vertex>>,
    pub(super) status: Vec<Result<(), CorrectorFailure>>,
    /// The row whose rays are next; 0 for the idle pass before a walk's first iteration.
    row: usize,
    /// The path length k + 1, or 0 when idle.
    len: usize,
    /// The candidates whose rays are in flight, in the order they were emitted.
    owners: Vec<usize>,
    /// Whether row k tests each candidate's last segment with a ray; without it the pass ends after
    /// placing the inner vertices (the walk then tests only the path it converges to).
    visibility: bool,
}

/// Where one corrector row's rays went in a `RayBatch`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Slot {
    bucket: Bucket,
    start: usize,
    pub(super) len: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bucket {
    /// Rays leaving x_0: every walk of one camera shares that origin, so packets of these rays get
    /// Embree's coherent traversal (see `intersect_batch`).
    FromStart,
    Inner,
    Visibility,
}

/// The rays of one round of corrector rows, across walks, and their answers.
#[derive(Default)]
pub(super) struct RayBatch {
    from_start: Vec<Ray>,
    inner: Vec<Ray>,
    visibility: Vec<Ray>,
    from_start_hits: Vec<Option<Hit>>,
    inner_hits: Vec<Option<Hit>>,
    occluded: Vec<bool>,
}

impl RayBatch {
    pub(super) fn clear(&mut self) {
        self.from_start.clear();
        self.inner.clear();
        self.visibility.clear();
    }

    fn rays_mut(&mut self, bucket: Bucket) -> &mut Vec<Ray> {
        match bucket {
            Bucket::FromStart => &mut self.from_start,
            Bucket::Inner => &mut self.inner,
            Bucket::Visibility => &mut self.visibility,
        }
    }

    fn rays(&self, slot: &Slot) -> &[Ray] {
        let rays = match slot.bucket {
            Bucket::FromStart => &self.from_start,
            Bucket::Inner => &self.inner,
            Bucket::Visibility => &self.visibility,
        };
        &rays[slot.start..slot.start + slot.len]
    }

    fn hits(&self, slot: &Slot) -> &[Option<Hit>] {
        let hits = match slot.bucket {
            Bucket::FromStart => &self.from_start_hits,
            Bucket::Inner => &self.inner_hits,
            Bucket::Visibility => unreachable!("visibility rows have no hits"),
        };
        &hits[slot.start..slot.start + slot.len]
    }

    /// One query per bucket (`batched`), or every ray on its own.
    pub(super) fn cast(&mut self, accel: &dyn RayQuery, batched: bool) {
        for (rays, hits) in
            [(&self.from_start, &mut self.from_start_hits), (&self.inner, &mut self.inner_hits)]
        {
            hits.clear();
            hits.resize(rays.len(), None);
            if rays.is_empty() {
                continue;
            }
            if batched {
                accel.intersect_batch(rays, hits);
            } else {
                for (ray, hit) in rays.iter().zip(hits.iter_mut()) {
                    *hit = accel.intersect(ray);
                }
            }
        }
        self.occluded.clear();
        self.occluded.resize(self.visibility.len(), false);
        if self.visibility.is_empty() {
            return;
        }
        if batched {
            accel.occluded_batch(&self.visibility, &mut self.occluded);
        } else {
            for (ray, blocked) in self.visibility.iter().zip(self.occluded.iter_mut()) {
                *blocked = accel.occluded(ray);
            }
        }
    }
}

impl CorrectorPass {
    pub(super) fn idle() -> CorrectorPass {
        CorrectorPass {
            fractions: Vec::new(),
            predicted: Vec::new(),
            built: Vec::new(),
            status: Vec::new(),
            row: 0,
            len: 0,
            owners: Vec::new(),
            visibility: true,
        }
    }

    /// Starts a pass from `current` with one candidate per step fraction; `visibility` as the field.
    pub(super) fn restart(
        &mut self,
        current: &[Vertex],
        fractions: &[f64],
        visibility: bool,
        predicted: impl Fn(usize, f64) -> Vec3,
    ) {
        self.visibility = visibility;
        let k = current.len() - 1;
        self.fractions.clear();
        self.fractions.extend_from_slice(fractions);
        self.predicted.clear();
        self.predicted.extend(
            fractions.iter().flat_map(|&f| (1..k).map(move |i| (i, f))).map(|(i, f)| predicted(i, f)),
        );
        self.built.resize_with(fractions.len(), Vec::new);
        for built in &mut self.built {
            built.clear();
            built.reserve(current.len());
            built.push(current[0]);
        }
        self.status.clear();
        self.status.resize(fractions.len(), Ok(()));
        self.row = 1;
        self.len = current.len();
    }

    /// Makes the pass idle (neither running nor finished), keeping its buffers.
    pub(super) fn stop(&mut self) {
        self.row = 0;
        self.len = 0;
    }

    pub(super) fn is_running(&self) -> bool {
        self.row >= 1 && self.row < self.len
    }

    pub(super) fn is_finished(&self) -> bool {
        self.len > 0 && self.row >= self.len
    }

    /// Appends the current row's rays to `batch`.
    pub(super) fn emit(&mut self, current: &[Vertex], batch: &mut RayBatch) -> Slot {
        let k = current.len() - 1;
        let i = self.row;
        self.owners.clear();
        let bucket = match i {
            1 => Bucket::FromStart,
            _ if i < k => Bucket::Inner,
            _ => Bucket::Visibility,
        };
        let rays = batch.rays_mut(bucket);
        let start = rays.len();
        for (c, (built, status)) in self.built.iter().zip(self.status.iter_mut()).enumerate() {
            if status.is_err() {
                continue;
            }
            if i == k {
                let (near, end) = (built[k - 1], current[k]);
                match Scene::shadow_segment(near.p, near.offset(), end.p, end.offset()) {
                    Some(ray) => {
                        rays.push(ray);
                        self.owners.push(c);
                    }
                    None => *status = Err(CorrectorFailure::Occluded),
                }
                continue;
            }
            let from = built[i - 1];
            let target = self.predicted[c * (k - 1) + i - 1];
            let Some(dir) = (target - from.p).try_normalize() else {
                *status = Err(CorrectorFailure::Missed { vertex: i });
                continue;
            };
            let origin = offset_origin(from.p, from.offset(), dir);
            // Aim from the offset origin: a ray parallel to from→target but displaced by the origin
            // offset (1e-4 relative) lands that far from the prediction, a noise floor the walk then
            // cannot converge below.
            let Some(dir) = (target - origin).try_normalize() else {
                *status = Err(CorrectorFailure::Missed { vertex: i });
                continue;
            };
            rays.push(Ray::new(origin, dir));
            self.owners.push(c);
        }
        Slot { bucket, start, len: rays.len() - start }
    }

    /// Takes the answers to the rays `emit` put in `slot` and moves to the next row.
    pub(super) fn absorb(&mut self, scene: &Scene, current: &[Vertex], batch: &RayBatch, slot: &Slot) {
        let k = current.len() - 1;
        let i = self.row;
        self.row += 1;
        if slot.bucket == Bucket::Visibility {
            let blocked = &batch.occluded[slot.start..slot.start + slot.len];
            for (i, &blocked) in blocked.iter().enumerate() {
                self.close_candidate(self.owners[i], current, blocked);
            }
            return;
        }
        for ((ray, hit), &c) in batch.rays(slot).iter().zip(batch.hits(slot)).zip(&self.owners) {
            let result = match hit.as_ref().and_then(|h| SurfaceInteraction::from_hit(scene, ray, h)) {
                None => Err(CorrectorFailure::Missed { vertex: i }),
                Some(si) if si.shape != current[i].shape => Err(CorrectorFailure::OtherShape { vertex: i }),
                Some(si) => Ok(Vertex::surface(scene, &si, current[i].beta)),
            };
            match result {
                Ok(v) => self.built[c].push(v),
                Err(e) => self.status[c] = Err(e),
            }
        }
        if self.row == k && !self.visibility {
            // No visibility row: the candidates end here, with the fixed end appended untested.
            for c in 0..self.built.len() {
                if self.status[c].is_ok() {
                    self.close_candidate(c, current, false);
                }
            }
            self.row += 1;
        }
    }

    /// Appends the fixed end x_k to candidate `c` and refuses it if its last segment is `blocked` or
    /// a vertex turned from reflection to transmission or back.
    fn close_candidate(&mut self, c: usize, current: &[Vertex], blocked: bool) {
        let k = current.len() - 1;
        let built = &mut self.built[c];
        built.push(current[k]);
        let failure = if blocked {
            Some(CorrectorFailure::Occluded)
        } else {
            (1..k)
                .find(|&v| same_side_sign(built, v) != same_side_sign(current, v))
                .map(|vertex| CorrectorFailure::ChangedSide { vertex })
        };
        if let Some(failure) = failure {
            self.status[c] = Err(failure);
        }
    }
}

/// Whether both neighbours of vertex `i` lie on the same side of its surface (reflection, not transmission).
fn same_side_sign(path: &[Vertex], i: usize) -> bool {
    let ng = path[i].ng;
    (ng.dot(path[i - 1].p - path[i].p) * ng.dot(path[i + 1].p - path[i].p)) > 0.0
}
