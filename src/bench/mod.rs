//! `hslt bench rays`: Embree against the pure-Rust BVH on the same scene, the same ray sets and the
//! same threads — build time, structure memory and Mrays/s for coherent, incoherent, shadow and
//! manifold-corrector-style ray bundles; also Embree's packet/stream/single paths and wrapper overhead.

pub mod mitsuba;
mod mutations;

pub use mutations::{bench_hslt, proposal_walks, stationary_starts, ProposalWalk};

use crate::accel::embree::PacketHint;
use crate::accel::{BvhScene, EmbreeScene, Hit};
use crate::geometry::{Frame, Ray, TriangleMesh, Vec2, Vec3};
use crate::sampling::Sampler;
use crate::sampling::{square_to_cosine_hemisphere, square_to_uniform_cone};
use crate::scene::{LoadOptions, Scene};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// The median of `values` (the upper of the middle two for an even count), sorting them in place.
pub fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// Rays per corrector bundle: a Newton step casts a handful of rays from one vertex. 16 is the
/// reference size; 8 and 64 show how the packet gain depends on it.
const BUNDLE_SIZES: [usize; 3] = [8, 16, 64];

/// Half-angle of the cone a corrector bundle's directions lie in.
const BUNDLE_CONE_DEGREES: f32 = 2.0;

/// A scene reduced to what the ray benchmark needs.
pub struct BenchScene {
    pub name: String,
    /// Shared with the loaded scene, not copied: the backends build from borrowed meshes.
    pub meshes: Vec<Arc<TriangleMesh>>,
    pub camera: Box<dyn Fn(Vec2) -> Ray + Sync>,
    /// Meshes whose points serve as shadow-ray targets (emitters, else all).
    pub light_meshes: Vec<usize>,
}

/// Loads a scene file for the benchmark.
pub fn load_scene(path: &Path, defines: &[(String, String)]) -> anyhow::Result<BenchScene> {
    let scene = Scene::load(path, &LoadOptions { defines: defines.to_vec(), accel: Default::default() })?;
    let meshes: Vec<Arc<TriangleMesh>> = scene.shapes.iter().map(|s| Arc::clone(&s.mesh)).collect();
    let mut light_meshes: Vec<usize> =
        (0..meshes.len()).filter(|&i| scene.shapes[i].light.is_some()).collect();
    if light_meshes.is_empty() {
        light_meshes = (0..meshes.len()).collect();
    }
    let (w, h) = (scene.film.width as f32, scene.film.height as f32);
    let camera = scene.camera.clone();
    Ok(BenchScene {
        name: path.display().to_string(),
        meshes,
        camera: Box::new(move |s| camera.generate_ray(Vec2::new(s.x * w, s.y * h))),
        light_meshes,
    })
}

/// A displaced, finely tessellated sphere (2·n² triangles) under a small square light, seen from outside.
pub fn large_scene(n: usize) -> BenchScene {
    let mut positions = Vec::with_capacity((n + 1) * (n + 1));
    for i in 0..=n {
        for j in 0..=n {
            let theta = std::f32::consts::PI * i as f32 / n as f32;
            let phi = std::f32::consts::TAU * j as f32 / n as f32;
            let r = 1.0 + 0.04 * (9.0 * theta).sin() * (13.0 * phi).cos() + 0.01 * (61.0 * phi).sin();
            positions.push(Vec3::new(
                r * theta.sin() * phi.cos(),
                r * theta.cos(),
                r * theta.sin() * phi.sin(),
            ));
        }
    }
    let id = |i: usize, j: usize| (i * (n + 1) + j) as u32;
    let mut indices = Vec::with_capacity(2 * n * n);
    for i in 0..n {
        for j in 0..n {
            indices.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            indices.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let sphere = TriangleMesh { name: "displaced sphere".into(), positions, indices, ..Default::default() };
    let light = TriangleMesh {
        name: "light".into(),
        positions: vec![
            Vec3::new(-0.5, 2.5, -0.5),
            Vec3::new(0.5, 2.5, -0.5),
            Vec3::new(0.5, 2.5, 0.5),
            Vec3::new(-0.5, 2.5, 0.5),
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    let floor = TriangleMesh {
        name: "floor".into(),
        positions: vec![
            Vec3::new(-5.0, -1.2, -5.0),
            Vec3::new(5.0, -1.2, -5.0),
            Vec3::new(5.0, -1.2, 5.0),
            Vec3::new(-5.0, -1.2, 5.0),
        ],
        indices: vec![[0, 2, 1], [0, 3, 2]],
        ..Default::default()
    };
    let eye = Vec3::new(0.0, 0.6, 3.2);
    let forward = (Vec3::new(0.0, -0.1, 0.0) - eye).normalize();
    let frame = Frame::from_normal(forward);
    BenchScene {
        name: format!("generated displaced sphere ({} triangles)", 2 * n * n + 4),
        meshes: vec![Arc::new(sphere), Arc::new(floor), Arc::new(light)],
        camera: Box::new(move |s| {
            let local = Vec3::new((2.0 * s.x - 1.0) * 0.6, (1.0 - 2.0 * s.y) * 0.6, 1.0);
            Ray::new(eye, frame.to_world(local).normalize())
        }),
        light_meshes: vec![2],
    }
}

fn random_point_on(meshes: &[Arc<TriangleMesh>], which: &[usize], sampler: &mut Sampler) -> Option<Vec3> {
    let candidates: Vec<usize> = which.iter().copied().filter(|&m| !meshes[m].indices.is_empty()).collect();
    let m = &meshes[*candidates
        .get((sampler.next_1d() * candidates.len() as f32) as usize % candidates.len().max(1))?];
    let prim = ((sampler.next_1d() * m.indices.len() as f32) as usize).min(m.indices.len() - 1);
    let [p0, p1, p2] = m.vertices(prim);
    let u = sampler.next_2d();
    let (a, b) = if u.x + u.y > 1.0 { (1.0 - u.x, 1.0 - u.y) } else { (u.x, u.y) };
    Some(p0 + a * (p1 - p0) + b * (p2 - p0))
}

/// The ray sets, built from Embree's answers so every backend traces identical rays.
pub struct RaySets {
    pub primary: Vec<Ray>,
    pub diffuse: Vec<Ray>,
    pub shadow: Vec<Ray>,
    /// Corrector bundles (closest hit) for each size in `BUNDLE_SIZES`.
    pub bundles: Vec<(usize, Vec<Ray>)>,
    /// Corrector visibility bundles of 16: segments from one vertex to targets on the surface the
    /// bundle's axis hits, as a corrector checks that a moved vertex still sees its neighbour.
    pub visibility: Vec<Ray>,
}

pub fn make_ray_sets(scene: &BenchScene, reference: &EmbreeScene, count: usize) -> RaySets {
    // Primary rays in scanline order of a square grid, so neighbours in the array are neighbours on film.
    let side = (count as f64).sqrt().ceil() as usize;
    let primary: Vec<Ray> = (0..side * side)
        .take(count)
        .map(|k| {
            (scene.camera)(Vec2::new(
                ((k % side) as f32 + 0.5) / side as f32,
                ((k / side) as f32 + 0.5) / side as f32,
            ))
        })
        .collect();
    let mut hits = vec![None; primary.len()];
    reference.intersect_batch(&primary, &mut hits);
    let surface: Vec<(Vec3, Vec3)> = primary
        .iter()
        .zip(&hits)
        .filter_map(|(r, h): (&Ray, &Option<Hit>)| {
            let h = (*h)?;
            let mut n = scene.meshes[h.geom_id as usize].geometric_normal(h.prim_id as usize);
            if n.dot(r.dir) > 0.0 {
                n = -n;
            }
            let p = r.at(h.t);
            let mesh = &scene.meshes[h.geom_id as usize];
            Some((p + n * crate::geometry::ray_epsilon(p, mesh.coordinate_scale(h.prim_id as usize)), n))
        })
        .collect();
    let mut sampler = Sampler::from_seed(99);
    let mut diffuse = Vec::with_capacity(count);
    let mut shadow = Vec::with_capacity(count);
    let mut bundles = Vec::new();
    let mut visibility = Vec::with_capacity(count);
    if !surface.is_empty() {
        for k in 0..count {
            let (p, n) = surface[k % surface.len()];
            let frame = Frame::from_normal(n);
            diffuse.push(Ray::new(p, frame.to_world(square_to_cosine_hemisphere(sampler.next_2d()))));
            if let Some(target) = random_point_on(&scene.meshes, &scene.light_meshes, &mut sampler) {
                shadow.push(Ray::segment(p, target - p, 1.0 - 1e-4));
            }
        }
        let cos_cone = BUNDLE_CONE_DEGREES.to_radians().cos();
        for size in BUNDLE_SIZES {
            // Corrector bundles: from one vertex, `size` rays within a small cone around a
            // cosine-distributed axis.
            let mut set = Vec::with_capacity(count);
            while set.len() < count {
                let (p, n) = surface[(sampler.next_1d() * surface.len() as f32) as usize % surface.len()];
                let axis = Frame::from_normal(
                    Frame::from_normal(n).to_world(square_to_cosine_hemisphere(sampler.next_2d())),
                );
                for _ in 0..size {
                    set.push(Ray::new(p, axis.to_world(square_to_uniform_cone(sampler.next_2d(), cos_cone))));
                }
            }
            set.truncate(count - count % size);
            bundles.push((size, set));
        }
        // Visibility bundles: each segment ends just short of where the bundle's axis meets the
        // scene, so rays near the axis are mostly clear and others may be blocked.
        let mut attempts = 0;
        while visibility.len() + 16 <= count && attempts < 4 * count {
            attempts += 1;
            let (p, n) = surface[(sampler.next_1d() * surface.len() as f32) as usize % surface.len()];
            let axis = Frame::from_normal(n).to_world(square_to_cosine_hemisphere(sampler.next_2d()));
            let Some(hit) = reference.intersect(&Ray::new(p, axis)) else { continue };
            let frame = Frame::from_normal(axis);
            for _ in 0..16 {
                let dir = frame.to_world(square_to_uniform_cone(sampler.next_2d(), cos_cone));
                visibility.push(Ray::segment(p, dir, hit.t * (1.0 - 1e-3)));
            }
        }
    }
    RaySets { primary, diffuse, shadow, bundles, visibility }
}

/// One way of answering a ray set, timed in chunks across the pool.
type Variant<'a> = &'a (dyn Fn(&[Ray]) + Sync);

/// Mrays/s of each variant applied to `rays` in chunks of `chunk` across the pool. The variants run
/// round-robin, five rounds, best round each, so a change in machine load hits all of them alike.
fn measure(pool: &rayon::ThreadPool, rays: &[Ray], chunk: usize, variants: &[Variant]) -> Vec<f64> {
    let mut best = vec![f64::INFINITY; variants.len()];
    for _ in 0..5 {
        for (f, b) in variants.iter().zip(best.iter_mut()) {
            let start = Instant::now();
            pool.install(|| rays.par_chunks(chunk).for_each(f));
            *b = b.min(start.elapsed().as_secs_f64());
        }
    }
    best.iter().map(|t| rays.len() as f64 / t.max(1e-9) * 1e-6).collect()
}

/// Single rays through the wrapper, counting hits: the counterpart of
/// [`EmbreeScene::raw_intersect1_loop`]. Never inlined, so callgrind can count it on its own.
#[inline(never)]
pub fn wrapper_intersect1_loop(embree: &EmbreeScene, rays: &[Ray]) -> usize {
    rays.iter().filter(|r| embree.intersect(r).is_some()).count()
}

/// Rays per block of the paired A/B timings: long enough to time (~0.1–1 ms), short enough for
/// hundreds of blocks per ray set; a multiple of every bundle size.
const AB_BLOCK: usize = 2048;

/// How much slower `a` is than `b` on the same rays, on the calling thread: each block of rays first
/// runs once untimed (so both see warm caches), then `a`, `b`, `b`, `a`; the block's ratio is a's
/// total time over b's. Returns the median over blocks and the number of blocks. Load changes
/// slower than a block cancel out of each ratio, and the median drops blocks hit by preemption.
fn paired_ratio(rays: &[Ray], a: &dyn Fn(&[Ray]), b: &dyn Fn(&[Ray])) -> (f64, usize) {
    let time = |f: &dyn Fn(&[Ray]), block: &[Ray]| {
        let start = Instant::now();
        f(block);
        start.elapsed().as_secs_f64()
    };
    let mut ratios: Vec<f64> = rays
        .chunks_exact(AB_BLOCK)
        .map(|block| {
            b(block);
            let (a1, b1, b2, a2) = (time(a, block), time(b, block), time(b, block), time(a, block));
            (a1 + a2) / (b1 + b2).max(1e-12)
        })
        .collect();
    if ratios.is_empty() {
        return (f64::NAN, 0);
    }
    ratios.sort_by(f64::total_cmp);
    (ratios[ratios.len() / 2], ratios.len())
}

fn resident_bytes() -> usize {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<usize>().ok())
        .map_or(0, |pages| pages * 4096)
}

/// Runs the comparison on `scene` and returns the report.
pub fn bench_rays(scene: &BenchScene, count: usize, pool: &rayon::ThreadPool) -> anyhow::Result<String> {
    let mut out = String::new();
    let triangles: usize = scene.meshes.iter().map(|m| m.indices.len()).sum();
    let _ = writeln!(
        out,
        "scene: {} — {} triangles, {} threads",
        scene.name,
        triangles,
        pool.current_num_threads()
    );

    let rss = resident_bytes();
    let start = Instant::now();
    let embree = pool.install(|| EmbreeScene::build(&scene.meshes))?;
    let embree_build = start.elapsed().as_secs_f64();
    let embree_mem = resident_bytes().saturating_sub(rss);
    let start = Instant::now();
    let bvh = pool.install(|| BvhScene::build(&scene.meshes))?;
    let bvh_build = start.elapsed().as_secs_f64();
    let _ = writeln!(
        out,
        "build      embree {:.3} s   bvh {:.3} s   (bvh/embree {:.2}x)",
        embree_build,
        bvh_build,
        bvh_build / embree_build.max(1e-9)
    );
    let _ = writeln!(
        out,
        "memory     embree ~{:.1} MB (resident growth during build)   bvh {:.1} MB (nodes + indices + triangles)",
        embree_mem as f64 / 1e6,
        bvh.memory_bytes() as f64 / 1e6
    );

    let sets = make_ray_sets(scene, &embree, count);
    let _ = writeln!(
        out,
        "Mrays/s    {:<24} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>8} {:>8} {:>9}",
        "ray set",
        "emb-1",
        "pkt-inc",
        "pkt-coh",
        "str-inc",
        "str-coh",
        "batch",
        "bvh-1",
        "batch/1",
        "best/bvh",
        "overhead"
    );
    let mut rows: Vec<(String, &[Ray], bool, usize)> = vec![
        ("primary (coherent)".into(), &sets.primary, false, 256),
        ("diffuse (incoherent)".into(), &sets.diffuse, false, 256),
        ("shadow (occlusion)".into(), &sets.shadow, true, 256),
    ];
    for (size, rays) in &sets.bundles {
        rows.push((format!("corrector bundles x{size}"), rays, false, *size));
    }
    rows.push(("corrector visibility x16".into(), &sets.visibility, true, 16));
    let mut ab_blocks = 0;
    let mut overhead_sides = Vec::new();
    let embree = &embree;
    for (label, rays, occlusion, chunk) in rows {
        if rays.is_empty() {
            continue;
        }
        let single = |c: &[Ray]| {
            for r in c {
                if occlusion {
                    std::hint::black_box(embree.occluded(r));
                } else {
                    std::hint::black_box(embree.intersect(r));
                }
            }
        };
        let packets = |hint: PacketHint| {
            move |c: &[Ray]| {
                if occlusion {
                    let mut o = vec![false; c.len()];
                    embree.occluded_packets(c, &mut o, hint);
                    std::hint::black_box(o);
                } else {
                    let mut h = vec![None; c.len()];
                    embree.intersect_packets(c, &mut h, hint);
                    std::hint::black_box(h);
                }
            }
        };
        let stream = |coherent: bool| {
            move |c: &[Ray]| {
                if occlusion {
                    let mut o = vec![false; c.len()];
                    embree.occluded_stream(c, &mut o, coherent);
                    std::hint::black_box(o);
                } else {
                    let mut h = vec![None; c.len()];
                    embree.intersect_stream(c, &mut h, coherent);
                    std::hint::black_box(h);
                }
            }
        };
        let batch = |c: &[Ray]| {
            if occlusion {
                let mut o = vec![false; c.len()];
                embree.occluded_batch(c, &mut o);
                std::hint::black_box(o);
            } else {
                let mut h = vec![None; c.len()];
                embree.intersect_batch(c, &mut h);
                std::hint::black_box(h);
            }
        };
        // The batch API over `c`, handed chunks of `chunk` rays as the timed runs do.
        let batch_in = |chunk: usize, c: &[Ray]| {
            for c in c.chunks(chunk) {
                batch(c);
            }
        };
        let rust = |c: &[Ray]| {
            for r in c {
                if occlusion {
                    std::hint::black_box(bvh.occluded(r));
                } else {
                    std::hint::black_box(bvh.intersect(r));
                }
            }
        };
        let (pkt_inc, pkt_coh) = (packets(PacketHint::Incoherent), packets(PacketHint::Coherent));
        let (str_inc, str_coh) = (stream(false), stream(true));
        let speeds =
            measure(pool, rays, chunk, &[&single, &pkt_inc, &pkt_coh, &str_inc, &str_coh, &batch, &rust]);
        let best = speeds[..6].iter().copied().fold(0.0, f64::max);
        // Batch over single rays, and (for intersection) the wrapper over the bare bindings, as paired
        // per-block ratios on one thread; the throughput columns above are only best-of-five.
        let (single_over_batch, blocks) =
            pool.install(|| paired_ratio(rays, &single, &|c| batch_in(chunk, c)));
        ab_blocks = ab_blocks.max(blocks);
        let overhead = if occlusion {
            "-".to_string()
        } else {
            let wrapper = |c: &[Ray]| {
                std::hint::black_box(wrapper_intersect1_loop(embree, c));
            };
            let raw = |c: &[Ray]| {
                std::hint::black_box(embree.raw_intersect1_loop(c));
            };
            // Measured in both orders and combined (geometric mean), so any bias from a side's
            // position in the A, B, B, A pattern cancels; the two one-sided figures show its size.
            let (forward, _) = pool.install(|| paired_ratio(rays, &wrapper, &raw));
            let (backward, _) = pool.install(|| paired_ratio(rays, &raw, &wrapper));
            overhead_sides.push((label.clone(), forward, 1.0 / backward));
            format!("{:+.1}%", 100.0 * ((forward / backward).sqrt() - 1.0))
        };
        let _ = write!(out, "           {label:<24}");
        for v in &speeds {
            let _ = write!(out, " {v:>7.2}");
        }
        let _ = writeln!(out, " {single_over_batch:>7.2}x {:>7.2}x {overhead:>9}", best / speeds[6]);
    }
    let _ = writeln!(
        out,
        "           emb-1 single rays through the wrapper; pkt-inc/pkt-coh {w}-wide packets with the incoherent/coherent hint;\n\
         \x20          str-inc/str-coh rtcIntersect1M/rtcOccluded1M with either hint; batch the batch API (packets, coherent hint\n\
         \x20          for packets sharing one origin); bvh-1 the Rust BVH; batch/1 (single-ray time over batch time) and overhead\n\
         \x20          (wrapper over raw rtcIntersect1 time - 1, geometric mean of both A/B orders) are medians of {} paired {AB_BLOCK}-ray blocks on one thread",
        ab_blocks,
        w = embree.packet_width(),
    );
    let _ = write!(out, "overhead   one-sided (wrapper as A / as B):");
    for (label, forward, backward) in &overhead_sides {
        let _ = write!(out, "  {label} {:+.1}%/{:+.1}%", 100.0 * (forward - 1.0), 100.0 * (backward - 1.0));
    }
    let _ = writeln!(out);
    Ok(out)
}
