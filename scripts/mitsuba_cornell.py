#!/usr/bin/env python3
"""The SCENES.md Cornell box with three spheres in Mitsuba 3 (the issue's
independent renderer), same settings as hotpath's pathtrace: `path`
integrator with 64 bounces (Mitsuba max_depth 65: depth 1 is emission seen
directly), Russian roulette from depth 5, box filter, independent sampler (--sampler picks another).

    pip install mitsuba==3.9.1   # plus Debian's libllvm19 for the llvm variant
    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so \
      python3 scripts/mitsuba_cornell.py --spp 64 --size 512 --out mi64.npy [--diffuse]

Prints the render time, wall and process CPU seconds (a first call includes
JIT compilation; --repeat runs it again warm) and writes linear RGB (H, W, 3) float32 as .npy.
"""
import argparse
import time

import mitsuba as mi
import numpy as np


def rgb(v):
    return {"type": "rgb", "value": v}


def quad(corner, u, v, bsdf, emitter=None):
    """hotpath's parallelogram corner + a u + b v as a Mitsuba rectangle
    ([-1, 1]^2, normal +z) mapped by the columns u/2, v/2, normalize(u x v), centre."""
    c, u, v = map(np.array, (corner, u, v))
    n = np.cross(u, v)
    n = n / np.linalg.norm(n)
    centre = c + (u + v) / 2
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = u / 2, v / 2, n, centre
    d = {"type": "rectangle", "to_world": mi.ScalarTransform4f(m.tolist()), "bsdf": bsdf}
    if emitter is not None:
        d["emitter"] = emitter
    return d


def scene(size, spp, diffuse, sampler="independent"):
    white = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb([0.73, 0.73, 0.73])}}
    red = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb([0.65, 0.05, 0.05])}}
    green = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb([0.12, 0.45, 0.15])}}
    sphere_white = {"type": "diffuse", "reflectance": rgb([0.73, 0.73, 0.73])}
    metal = {
        "type": "roughconductor",
        "material": "none",
        "distribution": "ggx",
        "alpha": 0.1,
        "sample_visible": True,
        "specular_reflectance": rgb([0.8, 0.8, 0.9]),
    }
    glass = {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}
    black = {"type": "diffuse", "reflectance": rgb([0.0, 0.0, 0.0])}
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 65, "rr_depth": 5},
        "sensor": {
            "type": "perspective",
            "fov": 40,
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3.5], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": sampler, "sample_count": spp},
        },
        "left": quad([-1, -1, -1], [0, 0, 2], [0, 2, 0], red),
        "right": quad([1, -1, -1], [0, 2, 0], [0, 0, 2], green),
        "back": quad([-1, -1, -1], [0, 2, 0], [2, 0, 0], white),
        "floor": quad([-1, -1, -1], [2, 0, 0], [0, 0, 2], white),
        "ceiling": quad([-1, 1, -1], [0, 0, 2], [2, 0, 0], white),
        "light": quad([-0.25, 0.99, -0.25], [0.5, 0, 0], [0, 0, 0.5], black, {"type": "area", "radiance": rgb([15, 15, 15])}),
        "a": {"type": "sphere", "center": [0.4, -0.6, -0.2], "radius": 0.4, "bsdf": sphere_white},
        "b": {"type": "sphere", "center": [-0.4, -0.7, 0.3], "radius": 0.3, "bsdf": sphere_white if diffuse else metal},
        "c": {"type": "sphere", "center": [0, -0.8, 0.5], "radius": 0.2, "bsdf": sphere_white if diffuse else glass},
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--passes", type=int, default=1, help="average this many renders (seeds seed..seed+passes-1)")
    ap.add_argument("--repeat", type=int, default=1, help="time the render this many times")
    ap.add_argument("--diffuse", action="store_true")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--sampler", default="independent", help="independent, stratified, multijitter, ldsampler, orthogonal")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    mi.set_variant(a.variant)
    sc = mi.load_dict(scene(a.size, a.spp, a.diffuse, a.sampler))
    for r in range(a.repeat):
        t, c = time.perf_counter(), time.process_time()
        acc = None
        for p in range(a.passes):
            img = np.array(mi.render(sc, seed=a.seed + p, spp=a.spp))
            acc = img if acc is None else acc + img
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        print(f"render {r}: {wall:.3f} s wall, {cpu:.3f} CPU-s ({a.size}x{a.size}, {a.spp} spp x {a.passes})", flush=True)
    np.save(a.out, (acc / a.passes).astype(np.float32))


if __name__ == "__main__":
    main()
