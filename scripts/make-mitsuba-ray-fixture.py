#!/usr/bin/env python3
"""Records what Mitsuba 3 hits along a set of rays, for tests/geometry_parity.rs.

Where two faces coincide (a glass cube resting on a floor), which one a ray meets first is decided by
the rounding of the triangle test, and a renderer compared against Mitsuba must round the same way
for the comparison to mean anything (docs/rough-glass.md). This script traces rays through the
contact version of scenes/nested-glass with Mitsuba's `scalar_rgb` variant and writes, per ray, the
origin and direction, the distance Mitsuba found and the index of the shape it hit.

    python3 -m venv venv && venv/bin/pip install mitsuba numpy
    venv/bin/python scripts/make-mitsuba-ray-fixture.py

Output: tests/data/geometry/nested-glass-contact-rays.bin, little-endian records of seven f32
(origin xyz, direction xyz, t) and one i32 (index into "shapes" of the .json beside it, -1 for a
miss), and that .json (scene, parameters, shape ids, Mitsuba version, ray count).

Embree picks its kernels by the CPU, and they do not all round alike: on a CPU with AVX2 but no
AVX-512 (an AMD EPYC, 2026-12-08) Mitsuba's hits differ from the main recording on 279 of the 2000
rays, and so do hslt's, identically. A recording made on such a CPU is kept beside the main one:

    venv/bin/python scripts/make-mitsuba-ray-fixture.py --recording avx2

writes only nested-glass-contact-rays.avx2.bin (the same rays) and lists it in the .json with the
CPU it was made on. tests/geometry_parity.rs requires hslt to agree with one of the recordings.
"""
import json
import os
import platform
import sys

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")

SCENE = "scenes/nested-glass/scene.xml"
PARAMS = {"outer_y": "0.6", "resx": "48", "resy": "36"}
OUT = "tests/data/geometry/nested-glass-contact-rays"


def cpu_name():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def cpu_flags():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    words = line.split(":", 1)[1].split()
                    return " ".join(w for w in words if w.startswith(("avx", "sse4", "fma")))
    except OSError:
        pass
    return ""


def main():
    recording = None
    if sys.argv[1:2] == ["--recording"] and len(sys.argv) == 3:
        recording = sys.argv[2]
    elif sys.argv[1:]:
        sys.exit("usage: make-mitsuba-ray-fixture.py [--recording NAME]")
    scene = mi.load_file(SCENE, **PARAMS)
    shapes = [s.id() for s in scene.shapes()]
    rng = np.random.default_rng(20261206)
    rays = []
    # Downward rays from inside the outer cube (its footprint is within |x|, |z| < 0.6): most meet the
    # bottom face and the floor at the same distance.
    for _ in range(1500):
        o = [rng.uniform(-0.4, 0.4), rng.choice([0.01, 0.1, 0.5, 1.1]), rng.uniform(-0.4, 0.4)]
        spread = rng.choice([0.0, 0.3, 1.0])
        d = np.array([rng.normal() * spread, -1.0, rng.normal() * spread])
        rays.append((o, d / np.linalg.norm(d)))
    # Rays from anywhere in the scene's box, in any direction.
    for _ in range(500):
        o = rng.uniform([-2, 0, -2], [2, 2.6, 2])
        d = rng.normal(size=3)
        rays.append((o, d / np.linalg.norm(d)))
    records = bytearray()
    for o, d in rays:
        o = np.asarray(o, dtype=np.float32)
        d = np.asarray(d, dtype=np.float32)
        si = scene.ray_intersect(mi.Ray3f(mi.ScalarPoint3f(*o), mi.ScalarVector3f(*d)))
        if si.is_valid():
            t, index = float(si.t), shapes.index(si.shape.id())
        else:
            t, index = float("inf"), -1
        records += np.array([*o, *d, t], dtype="<f4").tobytes() + np.array([index], dtype="<i4").tobytes()
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    if recording is not None:
        with open(OUT + ".json") as f:
            meta = json.load(f)
        if meta["shapes"] != shapes or meta["rays"] != len(rays):
            sys.exit("the main recording is of another scene or ray set: make it again first")
        name = f"{os.path.basename(OUT)}.{recording}.bin"
        with open(os.path.join(os.path.dirname(OUT), name), "wb") as f:
            f.write(records)
        meta.setdefault("recordings", {})[name] = f"{cpu_name()} ({cpu_flags()})"
        print("wrote", name, len(rays), "rays")
    else:
        with open(OUT + ".bin", "wb") as f:
            f.write(records)
        meta = {"scene": SCENE, "params": PARAMS, "shapes": shapes, "rays": len(rays),
                "mitsuba": mi.__version__, "variant": "scalar_rgb"}
        print("wrote", OUT + ".bin", len(rays), "rays")
    with open(OUT + ".json", "w") as f:
        json.dump(meta, f, indent=2, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main()
