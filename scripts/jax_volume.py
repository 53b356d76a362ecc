#!/usr/bin/env python3
"""JAX peer of the volume perf scenarios (issue 18; docs/PERF.md "volume").

The same emission-absorption forward as `f_fused` on the scenario of
`vol_fused_grid128_256px_f32` / `vol_grad_grid128_256px_f32`: the
`vol_grid_gaussian` density (A = 20, std 0.3) and the constant colour
(1, 0.5, 0.25) on 128^3 node-aligned grids over [-1, 1]^3 packed as
(z, y, x, 4), a 256x256 pinhole at (0, 0, 3) looking at the origin (fov_y
40), rays clipped to the box, fixed midpoint samples `t_k = t0 + (k + 1/2)
dt` with the last interval clipped at t1, trilinear interpolation,
`alpha = 1 - exp(-sigma dt_k)`, `T` by an exclusive cumulative sum of
`-sigma dt` (the log path), no early stop. f32, jit, rays in chunks under
`lax.map` with `jax.checkpoint` per chunk (memory). The backward is
`jax.grad` of `L = sum W . rgb`, `W = uniform - 0.5`, w.r.t. the packed grid.

JAX evaluates every lattice slot up to the longest ray (masked): "samples"
below counts the in-box samples only, the figure `f_fused` counts (without
its early stop). Not needed by CI; run by hand:

    pip install jax
    python3 scripts/jax_volume.py [--n 128] [--side 256] [--dt 0.01] [--repeats 3]

Prints one JSON line: forward and forward+backward seconds (medians), the
backward alone (difference), samples, samples/s and process CPU seconds.
"""
import argparse
import json
import math
import os
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np


def grid(n):
    x = np.linspace(-1.0, 1.0, n)
    z, y, xx = np.meshgrid(x, x, x, indexing="ij")
    sigma = 20.0 * np.exp(-(xx**2 + y**2 + z**2) / (2 * 0.3**2))
    g = np.empty((n, n, n, 4), np.float32)
    g[..., 0] = sigma
    g[..., 1:] = np.array([1.0, 0.5, 0.25], np.float32)
    return jnp.asarray(g)


def rays(side):
    f = 1.0 / math.tan(math.radians(40.0) / 2)
    v, u = np.meshgrid(np.arange(side) + 0.5, np.arange(side) + 0.5, indexing="ij")
    px = (2 * u / side - 1)
    py = 1 - 2 * v / side
    d = np.stack([px, py, -f * np.ones_like(px)], -1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(np.array([0.0, 0.0, 3.0]), d.shape)
    with np.errstate(divide="ignore"):
        inv = 1.0 / d
    ta, tb = (-1 - o) * inv, (1 - o) * inv
    t0 = np.maximum(np.minimum(ta, tb).max(1), 0.0)
    t1 = np.maximum(ta, tb).min(1)
    t1 = np.where(t1 > t0, t1, t0)
    return (jnp.asarray(o, jnp.float32), jnp.asarray(d, jnp.float32),
            jnp.asarray(t0, jnp.float32), jnp.asarray(t1, jnp.float32))


def make(n, dt, kmax, chunk):
    scale = (n - 1) / 2.0

    def trilinear(g, x):
        u = jnp.clip((x + 1.0) * scale, 0.0, n - 1.0)
        i0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, n - 2)
        f = u - i0
        out = 0.0
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    w = ((f[..., 0] if dx else 1 - f[..., 0]) *
                         (f[..., 1] if dy else 1 - f[..., 1]) *
                         (f[..., 2] if dz else 1 - f[..., 2]))
                    out = out + w[..., None] * g[i0[..., 2] + dz, i0[..., 1] + dy, i0[..., 0] + dx]
        return out

    @jax.checkpoint
    def render_chunk(g, o, d, t0, t1):
        k = jnp.arange(kmax, dtype=jnp.float32)
        a = t0[:, None] + k * dt
        b = jnp.minimum(t0[:, None] + (k + 1) * dt, t1[:, None])
        valid = a < t1[:, None]
        h = jnp.where(valid, b - a, 0.0)
        t = (a + b) * 0.5
        x = o[:, None, :] + t[..., None] * d[:, None, :]
        v = trilinear(g, x)
        tau = jnp.maximum(v[..., 0], 0.0) * h
        logt = jnp.cumsum(tau, axis=1) - tau
        w = jnp.exp(-logt) * -jnp.expm1(-tau)
        return jnp.sum(w[..., None] * v[..., 1:], axis=1)

    def render(g, o, d, t0, t1):
        m = o.shape[0] // chunk
        r = jax.lax.map(lambda a: render_chunk(g, *a),
                        (o.reshape(m, chunk, 3), d.reshape(m, chunk, 3),
                         t0.reshape(m, chunk), t1.reshape(m, chunk)))
        return r.reshape(-1, 3)

    return render


def cpu_s():
    t = os.times()
    return t.user + t.system


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--n", type=int, default=128)
    p.add_argument("--side", type=int, default=256)
    p.add_argument("--dt", type=float, default=0.01)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--chunk", type=int, default=2048)
    a = p.parse_args()
    g = grid(a.n)
    o, d, t0, t1 = rays(a.side)
    kmax = int(math.ceil(float(jnp.max(t1 - t0)) / a.dt)) + 1
    samples = int(jnp.sum(jnp.ceil(jnp.maximum(t1 - t0, 0.0) / a.dt)))
    render = make(a.n, a.dt, kmax, a.chunk)
    wts = jnp.asarray(np.random.default_rng(0).uniform(size=(o.shape[0], 3)) - 0.5, jnp.float32)
    fwd = jax.jit(render)
    loss = jax.jit(jax.value_and_grad(lambda gg: jnp.sum(wts * render(gg, o, d, t0, t1))))
    fwd(g, o, d, t0, t1).block_until_ready()
    loss(g)[1].block_until_ready()
    tf, tb, cf, cb = [], [], [], []
    for _ in range(a.repeats):
        c, s = cpu_s(), time.perf_counter()
        fwd(g, o, d, t0, t1).block_until_ready()
        tf.append(time.perf_counter() - s)
        cf.append(cpu_s() - c)
        c, s = cpu_s(), time.perf_counter()
        loss(g)[1].block_until_ready()
        tb.append(time.perf_counter() - s)
        cb.append(cpu_s() - c)
    f, fb = statistics.median(tf), statistics.median(tb)
    print(json.dumps({
        "jax": jax.__version__, "samples": samples, "lattice_slots": int(o.shape[0]) * kmax,
        "forward_s": f, "forward_backward_s": fb, "backward_s": fb - f,
        "bwd_fwd_ratio": (fb - f) / f, "samples_per_s": samples / f,
        "fwd_bwd_samples_per_s": samples / fb,
        "forward_cpu_s": statistics.median(cf), "forward_backward_cpu_s": statistics.median(cb),
        "samples_per_cpu_s": samples / statistics.median(cf),
    }))


if __name__ == "__main__":
    main()
