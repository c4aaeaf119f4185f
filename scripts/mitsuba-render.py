#!/usr/bin/env python3
"""Renders a scene with Mitsuba 3 in passes, for references and for Mitsuba's own error at a sample count.

A measurement tool beside scripts/make-mitsuba-references.py (which makes the small references the test
suite reads): this one renders any scene at any size, averaging passes of --pass-spp samples per pixel
with seeds --seed, --seed + 1, ..., and rewrites the output atomically after every pass, so a long
reference can be stopped at any point and is usable as it stands. Mitsuba is a test oracle in a
development venv (`python3 -m venv venv && venv/bin/pip install mitsuba numpy`; `llvm_ad_rgb` also
needs Debian's libllvm19), never a dependency of hslt.

    # the 256x192 nested-glass reference of docs/rough-glass.md (32768 spp, about 25 min on 2 cores)
    venv/bin/python scripts/mitsuba-render.py scenes/nested-glass/scene.xml ref.exr \\
        -D resx=256 -D resy=192 --pass-spp 1024 --passes 32 --seed 1
    # Mitsuba's own error at 2048 spp: independent renders, compared with `hslt error`
    venv/bin/python scripts/mitsuba-render.py scenes/nested-glass/scene.xml mts_1001.exr \\
        -D resx=256 -D resy=192 --pass-spp 2048 --passes 1 --seed 1001
"""
import argparse
import os
import time

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("output", help="an .exr path, rewritten atomically after each pass")
    parser.add_argument("-D", dest="params", action="append", default=[], metavar="NAME=VALUE",
                        help="scene parameter, as hslt's -D")
    parser.add_argument("--pass-spp", type=int, default=1024)
    parser.add_argument("--passes", type=int, default=1)
    parser.add_argument("--seed", type=int, default=1, help="seed of the first pass; pass k uses seed + k")
    parser.add_argument("--variant", default="llvm_ad_rgb")
    args = parser.parse_args()
    if not args.output.endswith(".exr"):
        parser.error("the output must be an .exr file")
    params = {}
    for p in args.params:
        name, sep, value = p.partition("=")
        if not sep:
            parser.error(f"-D {p}: expected NAME=VALUE")
        params[name] = value

    mi.set_variant(args.variant)
    scene = mi.load_file(args.scene, **params)
    # Mitsuba's writer picks the format from the extension, so the temporary name keeps .exr.
    tmp = args.output[:-4] + f".tmp-{os.getpid()}.exr"
    total = 0.0
    for k in range(args.passes):
        started = time.time()
        img = np.array(mi.render(scene, spp=args.pass_spp, seed=args.seed + k), dtype=np.float64)[..., :3]
        total = total + img
        mi.Bitmap((total / (k + 1)).astype(np.float32)).write(tmp)
        os.replace(tmp, args.output)
        print(f"pass {k + 1}/{args.passes}: {time.time() - started:.1f} s, {(k + 1) * args.pass_spp} spp",
              flush=True)


if __name__ == "__main__":
    main()
