#!/usr/bin/env python3
"""Speed against error for the transport integrator tiers (docs/PERF.md).

Renders TESTS/scenes/schwarzschild_deflection.yaml with 1000 rays (the 8
SCENES.md impact parameters repeated 125 times, one thread) for each tier and step/tolerance
setting, and compares the deflections with the finite-distance quadrature
(transport.deflection_finite, f64; values below, printed by that op). Prints a
markdown table and writes a log-log PNG with axes and a legend (`hpjudge plot`).

Usage: scripts/transport_speed_error.py HPJUDGE OUT_PNG
"""
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REF = np.array([3.5473379929077993, 1.707388238337007, 0.8427298476635312, 0.5703954547575436,
                0.196133332243289, -0.014958200571810742, -0.15911179753089888, -0.5959046477879126])
SCENE = "TESTS/scenes/schwarzschild_deflection.yaml"
RUNS = [
    ("rk4", "f64", "{type: rk4, eta: %g}", [0.1, 0.05, 0.02, 0.01, 0.005]),
    ("dopri5", "f64", "{type: dopri5, rtol: %g, atol: 1.0e-14, h0: 1}", [1e-6, 1e-8, 1e-10, 1e-12]),
    ("dopri5_fixed", "f64", "{type: dopri5_fixed, eta: %g}", [0.2, 0.1, 0.05, 0.02]),
    ("implicit_midpoint", "f64", "{type: implicit_midpoint, eta: %g}", [0.02, 0.01, 0.005, 0.002]),
    ("rk4", "f32", "{type: rk4, eta: %g}", [0.1, 0.05, 0.02]),
    ("dopri5", "f32", "{type: dopri5, rtol: %g, atol: 1.0e-7, h0: 1}", [1e-4, 1e-6]),
]


def render(hp, integrator, precision, reps=3):
    best = None
    for _ in range(reps):
        with tempfile.TemporaryDirectory() as d:
            cmd = [hp, "render", SCENE, "--out", d, "--precision", precision, "--set", "task.repeat=125",
                   "--set", "integrator=" + integrator, "--threads", "1"]
            r = subprocess.run(cmd, capture_output=True, text=True, check=True)
            m = dict(line.split(": ", 1) for line in (r.stdout + r.stderr).splitlines() if ": " in line)
            defl = np.load(Path(d) / "deflection.npy").astype(np.float64)[:8]
            steps = np.load(Path(d) / "steps.npy")[:8]
        t = float(m["s_per_1000_rays"])
        if best is None or t < best[0]:
            best = (t, np.abs(defl - REF).max(), int(steps.mean()))
    return best


def plot(hp, path, series):
    """Log-log chart (x = error, y = s per 1000 rays), one series per tier, drawn by `hpjudge plot`."""
    import json
    chart = {"title": "transport: integrator tiers, speed against error", "x_label": "max deflection error",
             "y_label": "seconds per 1000 rays", "log_x": True, "log_y": True,
             "series": [{"name": f"{name} {prec}", "xs": [max(e, 1e-16) for (_, _, e, _) in rows],
                         "ys": [t for (_, t, _, _) in rows]} for name, prec, rows in series]}
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
        json.dump(chart, f)
    subprocess.run([hp, "plot", f.name, "-o", path], check=True, capture_output=True)
    Path(f.name).unlink()


def main():
    hp, out = sys.argv[1], sys.argv[2]
    series = []
    print("| tier | precision | setting | s / 1000 rays | max deflection error | mean steps |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, prec, fmt, values in RUNS:
        rows = []
        for v in values:
            t, e, s = render(hp, fmt % v, prec)
            rows.append((v, t, e, s))
            print(f"| {name} | {prec} | {fmt % v} | {t:.3g} | {e:.2e} | {s} |", flush=True)
        series.append((name, prec, rows))
    plot(hp, out, series)


if __name__ == "__main__":
    main()
