#!/usr/bin/env python3
"""Renders the small Mitsuba 3 reference images that tests/mitsuba_reference.rs compares against.

Mitsuba 3 reads the same scene XML as hslt. Install it with `pip install mitsuba` (the scalar_rgb
variant needs nothing else). Run from the repository root:

    python3 scripts/make-mitsuba-references.py

Each reference is rendered at a small resolution with many samples so that its own noise is far
below the noise of the test renders it is compared with; the settings are recorded next to the image.
"""
import json
import os
import sys

import mitsuba as mi

mi.set_variant("scalar_rgb")

# name -> (scene file, parameter overrides, samples per pixel)
REFERENCES = {
    "cornell-box": ("scenes/cornell-box/scene.xml", {"resx": "64", "resy": "64"}, 4096),
    "materials": ("scenes/materials/scene.xml", {"resx": "64", "resy": "48"}, 8192),
    # Mitsuba's light tracer (`ptracer`) resolves the caustic through the glass ball far better than its
    # path tracer; BDPT is compared against it. Samples are light paths per pixel here.
    "caustic": ("scenes/caustic/scene.xml", {"resx": "32", "resy": "32", "integrator": "ptracer"}, 65536),
}

OUT_DIR = "tests/references/mitsuba"


def main(names):
    os.makedirs(OUT_DIR, exist_ok=True)
    for name in names or REFERENCES:
        scene_file, params, spp = REFERENCES[name]
        params = dict(params, spp=str(spp))
        scene = mi.load_file(scene_file, **params)
        image = mi.render(scene, seed=1)
        out = os.path.join(OUT_DIR, name + ".exr")
        mi.Bitmap(image).write(out)
        with open(os.path.join(OUT_DIR, name + ".json"), "w") as f:
            json.dump({"scene": scene_file, "params": params, "mitsuba": mi.__version__,
                       "variant": "scalar_rgb"}, f, indent=2, sort_keys=True)
            f.write("\n")
        print("wrote", out)


if __name__ == "__main__":
    main(sys.argv[1:])
