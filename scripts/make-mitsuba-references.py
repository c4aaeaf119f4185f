#!/usr/bin/env python3
"""Renders the small Mitsuba 3 reference images that tests/references.rs compares against.

Mitsuba 3 reads the same scene XML as hslt. Install it with `pip install mitsuba numpy` (the
scalar_rgb variant needs nothing else). Run from the repository root:

    python3 scripts/make-mitsuba-references.py [NAME ...] [--self-error-only]

Each reference is rendered at a small resolution with many samples so that its own noise is far
below the noise of the test renders it is compared with; the settings are recorded next to the image.

References with a very high sample count use the `llvm_ad_rgb` variant (Debian's `libllvm19`; the
script points `DRJIT_LIBLLVM_PATH` at it unless it is set) and are rendered in passes of at most 4096
samples per pixel with seeds 1, 2, ..., averaged, to bound memory.

Scenes whose noise is heavy-tailed (light reaching the camera through near-specular glass) defeat a
χ² test built on a render's own variance estimate. For those, the script also measures Mitsuba's own
error: independent Mitsuba renders at the sample count the test uses, with seeds 1001, 1002, ...,
compared with the reference by the same metrics as `hslt error` (relative MSE of block means, with
ε = 0.01, and the flux ratio). They go into the JSON as `self_error`, and the test calls hslt right
when its error is no worse than Mitsuba's (`--self-error-only` measures them again without
re-rendering the reference).
"""
import json
import os
import sys

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402

# name -> (scene file, parameter overrides, samples per pixel, variant, self-error settings)
REFERENCES = {
    "cornell-box": ("scenes/cornell-box/scene.xml", {"resx": "64", "resy": "64"}, 4096, "scalar_rgb", None),
    "materials": ("scenes/materials/scene.xml", {"resx": "64", "resy": "48"}, 8192, "scalar_rgb", None),
    # Mitsuba's light tracer (`ptracer`) resolves the caustic through the glass ball far better than its
    # path tracer; BDPT is compared against it. Samples are light paths per pixel here.
    "caustic": ("scenes/caustic/scene.xml", {"resx": "32", "resy": "32", "integrator": "ptracer"}, 65536,
                "scalar_rgb", None),
    # Nested rough glass (issue 28): Mitsuba's path tracer, 2^18 samples per pixel; its own error at
    # 4096 spp over eight seeds, in 6x6 blocks.
    "nested-glass": ("scenes/nested-glass/scene.xml", {"resx": "48", "resy": "36"}, 262144, "llvm_ad_rgb",
                     {"spp": 4096, "runs": 8, "block": 6}),
}

PASS_SPP = 4096

OUT_DIR = "tests/references/mitsuba"


def render(scene, spp, seed, variant):
    """Mean of passes of at most PASS_SPP samples (seeds seed, seed + 1, ...) as float64 RGB."""
    if variant == "scalar_rgb":
        return np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)[..., :3]
    passes = (spp + PASS_SPP - 1) // PASS_SPP
    total = 0.0
    for i in range(passes):
        n = min(PASS_SPP, spp - i * PASS_SPP)
        total = total + np.array(mi.render(scene, spp=n, seed=seed + i), dtype=np.float64)[..., :3] * n
    return total / spp


def block_means(img, block):
    h, w, _ = img.shape
    bh, bw = -(-h // block), -(-w // block)
    out = np.zeros((bh, bw, 3))
    for by in range(bh):
        for bx in range(bw):
            out[by, bx] = img[by * block:(by + 1) * block, bx * block:(bx + 1) * block].mean(axis=(0, 1))
    return out


def rel_mse(img, ref, eps=0.01):
    return float(np.mean((img - ref) ** 2 / (ref ** 2 + eps)))


def self_error(scene, reference, settings, variant):
    spp, runs, block = settings["spp"], settings["runs"], settings["block"]
    ref_blocks = block_means(reference, block)
    block_rel, flux = [], []
    for k in range(runs):
        img = render(scene, spp, 1001 + k * 64, variant)
        block_rel.append(rel_mse(block_means(img, block), ref_blocks))
        flux.append(float(img.mean() / reference.mean()))
        print(f"  self-error run {k}: block relMSE {block_rel[-1]:.3e}, flux {flux[-1]:.4f}")
    return {"spp": spp, "block": block, "epsilon": 0.01, "block_rel_mse": block_rel, "flux_ratio": flux}


def main(args):
    self_error_only = "--self-error-only" in args
    names = [a for a in args if not a.startswith("--")]
    os.makedirs(OUT_DIR, exist_ok=True)
    for name in names or REFERENCES:
        scene_file, params, spp, variant, self_settings = REFERENCES[name]
        mi.set_variant(variant)
        out = os.path.join(OUT_DIR, name + ".exr")
        meta_path = os.path.join(OUT_DIR, name + ".json")
        scene = mi.load_file(scene_file, **dict(params, spp=str(spp)))
        if self_error_only:
            reference = np.array(mi.Bitmap(out), dtype=np.float64)[..., :3]
            with open(meta_path) as f:
                meta = json.load(f)
        else:
            reference = render(scene, spp, 1, variant)
            mi.Bitmap(reference.astype(np.float32)).write(out)
            meta = {"scene": scene_file, "params": dict(params, spp=str(spp)), "mitsuba": mi.__version__,
                    "variant": variant, "passes": 1 if variant == "scalar_rgb" else -(-spp // PASS_SPP)}
            print("wrote", out)
        if self_settings:
            meta["self_error"] = self_error(scene, reference, self_settings, variant)
        with open(meta_path, "w") as f:
            json.dump(meta, f, indent=2, sort_keys=True)
            f.write("\n")


if __name__ == "__main__":
    main(sys.argv[1:])
