#!/usr/bin/env python3
"""einsteinpy (0.5.0, `pip install einsteinpy`) on the same geodesics as
scripts/transport_speed_error.py: Schwarzschild photons from r = 1000 with
b = 6, 8, 10, 20, 100 (E = 1, L = b, equatorial), its Nulllike integrator
(fixed affine step delta), phi interpolated linearly at the outward r = 1000
crossing, error against the finite-distance quadrature (transport.deflection_finite).
Prints markdown rows: seconds per 1000 rays, max deflection error, steps.
"""
import time, math, numpy as np
from einsteinpy.geodesic import Nulllike
REF = {6: 1.707388238337007, 8: 0.8427298476635312, 10: 0.5703954547575436, 20: 0.196133332243289, 100: -0.15911179753089888}
r0 = 1000.0
for delta in [1.0, 0.5, 0.25]:
    errs, secs = [], 0.0
    for b, ref in REF.items():
        f = 1 - 2 / r0
        pr = -math.sqrt(1 / f**2 - b * b / (r0 * r0 * f))
        n = int(2300 / delta)
        t = time.time()
        try:
          g = Nulllike(metric="Schwarzschild", metric_params=(), position=[r0, math.pi / 2, 0.0], momentum=[pr, 0.0, b],
                     steps=n, delta=delta, return_cartesian=False, suppress_warnings=True)
        except OverflowError:
          errs.append(float('inf')); continue
        secs += time.time() - t
        tr = g.trajectory[1]
        r, phi = tr[:, 1], tr[:, 3]
        k = np.argmax((r[1:] >= r0) & (r[:-1] < r0) & (tr[1:, 5] > 0))
        w = (r0 - r[k]) / (r[k + 1] - r[k])
        ph = phi[k] + w * (phi[k + 1] - phi[k])
        errs.append(abs(ph - math.pi - ref))
    print(f"| einsteinpy Nulllike (Schwarzschild) | f64 | delta {delta} | {secs / len(REF) * 1000:.3g} | {max(errs):.2e} | {int(2300/delta)} |", flush=True)
