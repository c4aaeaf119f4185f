//! `hslt bench rays`: Embree against the pure-Rust BVH on the same scene, the same ray sets and the
//! same threads — build time, structure memory and Mrays/s for coherent, incoherent, shadow and
//! manifold-corrector-style ray bundles; also Embree's packet/stream/single paths and wrapper overhead.

use crate::accel::{BvhScene, EmbreeScene, Hit};
use crate::geometry::{Frame, Ray, TriangleMesh, Vec2, Vec3};
use crate::sampling::Sampler;
use crate::sampling::{square_to_cosine_hemisphere, square_to_uniform_cone};
use crate::scene::{LoadOptions, Scene};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// Rays per corrector bundle: a Newton step casts a handful of rays from one vertex.
const BUNDLE: usize = 16;

/// A scene reduced to what the ray benchmark needs.
pub struct BenchScene {
    pub name: String,
    pub meshes: Vec<TriangleMesh>,
    pub camera: Box<dyn Fn(Vec2) -> Ray + Sync>,
    /// Meshes whose points serve as shadow-ray targets (emitters, else all).
    pub light_meshes: Vec<usize>,
}

/// Loads a scene file for the benchmark.
pub fn load_scene(path: &Path, defines: &[(String, String)]) -> anyhow::Result<BenchScene> {
    let scene = Scene::load(path, &LoadOptions { defines: defines.to_vec(), accel: Default::default() })?;
    let meshes: Vec<TriangleMesh> = scene.shapes.iter().map(|s| (*s.mesh).clone()).collect();
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
        meshes: vec![sphere, floor, light],
        camera: Box::new(move |s| {
            let local = Vec3::new((2.0 * s.x - 1.0) * 0.6, (1.0 - 2.0 * s.y) * 0.6, 1.0);
            Ray::new(eye, frame.to_world(local).normalize())
        }),
        light_meshes: vec![2],
    }
}

fn random_point_on(meshes: &[TriangleMesh], which: &[usize], sampler: &mut Sampler) -> Option<Vec3> {
    let candidates: Vec<usize> = which.iter().copied().filter(|&m| !meshes[m].indices.is_empty()).collect();
    let m = &meshes[*candidates
        .get((sampler.next_1d() * candidates.len() as f32) as usize % candidates.len().max(1))?];
    let prim = ((sampler.next_1d() * m.indices.len() as f32) as usize).min(m.indices.len() - 1);
    let [p0, p1, p2] = m.vertices(prim);
    let u = sampler.next_2d();
    let (a, b) = if u.x + u.y > 1.0 { (1.0 - u.x, 1.0 - u.y) } else { (u.x, u.y) };
    Some(p0 + a * (p1 - p0) + b * (p2 - p0))
}

/// The four ray sets, built from Embree's answers so every backend traces identical rays.
pub struct RaySets {
    pub primary: Vec<Ray>,
    pub diffuse: Vec<Ray>,
    pub shadow: Vec<Ray>,
    pub bundles: Vec<Ray>,
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
            Some((p + n * crate::geometry::ray_epsilon(p), n))
        })
        .collect();
    let mut sampler = Sampler::from_seed(99);
    let mut diffuse = Vec::with_capacity(count);
    let mut shadow = Vec::with_capacity(count);
    let mut bundles = Vec::with_capacity(count);
    if !surface.is_empty() {
        for k in 0..count {
            let (p, n) = surface[k % surface.len()];
            let frame = Frame::from_normal(n);
            diffuse.push(Ray::new(p, frame.to_world(square_to_cosine_hemisphere(sampler.next_2d()))));
            if let Some(target) = random_point_on(&scene.meshes, &scene.light_meshes, &mut sampler) {
                shadow.push(Ray::segment(p, target - p, 1.0 - 1e-4));
            }
        }
        // Corrector bundles: from one vertex, BUNDLE rays towards targets within a 2-degree cone.
        while bundles.len() < count {
            let (p, n) = surface[(sampler.next_1d() * surface.len() as f32) as usize % surface.len()];
            let axis = Frame::from_normal(
                Frame::from_normal(n).to_world(square_to_cosine_hemisphere(sampler.next_2d())),
            );
            for _ in 0..BUNDLE {
                bundles.push(Ray::new(
                    p,
                    axis.to_world(square_to_uniform_cone(sampler.next_2d(), 2f32.to_radians().cos())),
                ));
            }
        }
        bundles.truncate(count);
    }
    RaySets { primary, diffuse, shadow, bundles }
}

/// Mrays/s of `f` applied to `rays` in chunks of `chunk` across the pool; best of three runs.
fn measure(pool: &rayon::ThreadPool, rays: &[Ray], chunk: usize, f: &(dyn Fn(&[Ray]) + Sync)) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let start = Instant::now();
        pool.install(|| rays.par_chunks(chunk).for_each(f));
        best = best.min(start.elapsed().as_secs_f64());
    }
    rays.len() as f64 / best.max(1e-9) * 1e-6
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
        "Mrays/s    {:<22} {:>9} {:>9} {:>9} {:>9} {:>9} {:>10} {:>10} {:>9}",
        "ray set", "emb-1", "emb-pkt", "emb-strm", "raw-1", "bvh-1", "best/bvh", "pkt/1", "overhead"
    );
    for (label, rays, occlusion, chunk) in [
        ("primary (coherent)", &sets.primary, false, 256),
        ("diffuse (incoherent)", &sets.diffuse, false, 256),
        ("shadow (occlusion)", &sets.shadow, true, 256),
        ("corrector bundles x16", &sets.bundles, false, BUNDLE),
    ] {
        if rays.is_empty() {
            continue;
        }
        let coherent = label.starts_with("primary") || label.starts_with("corrector");
        let single = measure(pool, rays, chunk, &|c| {
            for r in c {
                if occlusion {
                    std::hint::black_box(embree.occluded(r));
                } else {
                    std::hint::black_box(embree.intersect(r));
                }
            }
        });
        let packets = measure(pool, rays, chunk, &|c| {
            if occlusion {
                let mut o = vec![false; c.len()];
                embree.occluded_batch(c, &mut o);
                std::hint::black_box(o);
            } else {
                let mut h = vec![None; c.len()];
                embree.intersect_batch(c, &mut h);
                std::hint::black_box(h);
            }
        });
        let stream = measure(pool, rays, chunk, &|c| {
            if occlusion {
                let mut o = vec![false; c.len()];
                embree.occluded_stream(c, &mut o, coherent);
                std::hint::black_box(o);
            } else {
                let mut h = vec![None; c.len()];
                embree.intersect_stream(c, &mut h, coherent);
                std::hint::black_box(h);
            }
        });
        // The raw loop and the wrapper's single-ray path do the same work only for intersection.
        let raw = if occlusion {
            f64::NAN
        } else {
            measure(pool, rays, chunk, &|c| {
                std::hint::black_box(embree.raw_intersect1_loop(c));
            })
        };
        let rust = measure(pool, rays, chunk, &|c| {
            for r in c {
                if occlusion {
                    std::hint::black_box(bvh.occluded(r));
                } else {
                    std::hint::black_box(bvh.intersect(r));
                }
            }
        });
        let best = single.max(packets).max(stream);
        let overhead =
            if raw.is_nan() { "-".to_string() } else { format!("{:+.1}%", 100.0 * (raw / single - 1.0)) };
        let _ = writeln!(
            out,
            "           {label:<22} {single:>9.2} {packets:>9.2} {stream:>9.2} {raw:>9.2} {rust:>9.2} {:>9.2}x {:>9.2}x {overhead:>9}",
            best / rust,
            packets / single
        );
    }
    let _ = writeln!(out, "           emb-1 single rays through the wrapper, emb-pkt {}-wide packets, emb-strm rtcIntersect1M/rtcOccluded1M,", embree.packet_width());
    let _ = writeln!(out, "           raw-1 rtcIntersect1 straight from the bindings; overhead = wrapper time over raw time - 1");
    Ok(out)
}
