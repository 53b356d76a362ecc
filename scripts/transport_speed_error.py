#!/usr/bin/env python3
"""Speed against error for the transport integrator tiers (docs/PERF.md).

Renders TESTS/scenes/schwarzschild_deflection.yaml with 1000 rays (the 8
SCENES.md impact parameters repeated 125 times, one thread) for each tier and step/tolerance
setting, and compares the deflections with the finite-distance quadrature
(transport.deflection_finite, f64; values below, printed by that op). Prints a
markdown table and writes a log-log PNG (no plotting library needed).

Usage: scripts/transport_speed_error.py HPJUDGE OUT_PNG
"""
import struct
import subprocess
import sys
import tempfile
import zlib
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


def png(path, series, w=640, h=420):
    """Log-log scatter (x = error, y = s per 1000 rays) with one colour per series."""
    img = np.full((h, w, 3), 255, np.uint8)
    pts = [(np.log10(max(e, 1e-16)), np.log10(t)) for _, _, rows in series for (_, t, e, _) in rows]
    x0, x1 = min(p[0] for p in pts) - 0.3, max(p[0] for p in pts) + 0.3
    y0, y1 = min(p[1] for p in pts) - 0.2, max(p[1] for p in pts) + 0.2
    px = lambda x: int(40 + (x - x0) / (x1 - x0) * (w - 60))
    py = lambda y: int(h - 30 - (y - y0) / (y1 - y0) * (h - 50))
    img[h - 30, 40:w - 20] = 0
    img[20:h - 30, 40] = 0
    for dec in range(int(np.floor(x0)), int(np.ceil(x1)) + 1):
        if x0 <= dec <= x1:
            img[h - 34:h - 26, px(dec)] = 0
    colours = [(200, 30, 30), (30, 120, 200), (30, 160, 60), (150, 60, 180), (230, 140, 20), (90, 90, 90)]
    for (name, prec, rows), col in zip(series, colours):
        prev = None
        for (_, t, e, _) in rows:
            cx, cy = px(np.log10(max(e, 1e-16))), py(np.log10(t))
            img[max(cy - 3, 0):cy + 4, max(cx - 3, 0):cx + 4] = col
            if prev:
                n = max(abs(cx - prev[0]), abs(cy - prev[1]), 1)
                for k in range(n):
                    img[int(prev[1] + (cy - prev[1]) * k / n), int(prev[0] + (cx - prev[0]) * k / n)] = col
            prev = (cx, cy)
    raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


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
    png(out, series)


if __name__ == "__main__":
    main()
