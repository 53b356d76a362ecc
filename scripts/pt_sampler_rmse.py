#!/usr/bin/env python3
"""RMSE at equal spp of our samplers and Mitsuba's on the Cornell box (the
error half of the equal-error ratio in docs/PERF.md; the time half is
scripts/pt_vs_mitsuba.sh). 128x128, SPP (64), seeds 1..SEEDS (16); RMSE of
radiance clamped to [0, 1] against the committed 16384-spp Mitsuba
reference, as `pathtrace.rmse_vs_reference` computes it.

    python3 scripts/pt_sampler_rmse.py [target/release/hpjudge] [--no-mitsuba]
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
SPP = int(os.environ.get("SPP", "64"))
SEEDS = range(1, int(os.environ.get("SEEDS", "16")) + 1)
REF = np.load(os.path.join(ROOT, "GOLDENS/pathtrace/mitsuba_cornell_box_128_16384spp.npy"))


def rmse(img):
    return float(np.sqrt(np.mean((np.clip(img, 0, 1) - np.clip(REF, 0, 1)) ** 2)))


def report(name, v):
    print(f"{name}: mean {np.mean(v):.5f} (min {min(v):.5f}, max {max(v):.5f}, n {len(v)})", flush=True)


def ours(binary, sampler):
    v = []
    with tempfile.TemporaryDirectory() as out:
        for s in SEEDS:
            subprocess.run([binary, "render", os.path.join(ROOT, "TESTS/scenes/cornell_box.yaml"),
                            "--set", "width=128", "--set", "height=128", "--set", f"spp={SPP}",
                            "--set", f"seed={s}", "--set", f"sampler.type={sampler}", "--out", out],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            v.append(rmse(np.load(os.path.join(out, "image.npy"))))
    report(f"ours {sampler}", v)


def mitsuba(sampler):
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    import mitsuba as mi
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import mitsuba_cornell
    mi.set_variant("llvm_ad_rgb")
    sc = mi.load_dict(mitsuba_cornell.scene(128, SPP, False, sampler))
    report(f"mitsuba {sampler}", [rmse(np.array(mi.render(sc, seed=s, spp=SPP))) for s in SEEDS])


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    binary = args[0] if args else os.path.join(ROOT, "target/release/hpjudge")
    for smp in ["independent", "sobol"]:
        ours(binary, smp)
    if "--no-mitsuba" not in sys.argv:
        for smp in ["independent", "multijitter"]:
            mitsuba(smp)
