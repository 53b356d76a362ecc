#!/usr/bin/env python3
"""Renders SCENES.md `vol_gaussian` through hotpath's C ABI from Python.

ctypes and numpy only (no compiled extension): hp_ray -> hp_samp -> hp_int ->
hp_img on numpy arrays passed as hp_tensor views (strides in elements).

    python3 examples/python/hp_render.py --lib target/release/libhotpath_capi.so \
        [--compare out/ref/rgb.npy] [--out rgb.npy]

With --compare it prints `bit-identical` when its rgb equals the given .npy
byte for byte (what `hpjudge render TESTS/scenes/vol_gaussian.yaml` writes),
else the largest difference, and exits 1. docs/c-api.md documents the API.
"""
import argparse
import ctypes as C
import sys

import numpy as np

HP_OK = 0
HP_ABI_VERSION = 1
HP_DTYPE = {np.dtype(np.float32): 0, np.dtype(np.float64): 1, np.dtype(np.int32): 2,
            np.dtype(np.uint32): 3, np.dtype(np.uint8): 4}
HP_ANALYTIC_GAUSSIAN = 2
HP_STAGE_RAY, HP_STAGE_SAMP, HP_STAGE_INT = 0, 1, 2


class Tensor(C.Structure):
    _fields_ = [("data", C.c_void_p), ("dtype", C.c_uint32), ("memspace", C.c_uint32),
                ("ndim", C.c_uint32), ("reserved", C.c_uint32),
                ("shape", C.c_int64 * 4), ("stride", C.c_int64 * 4)]


class Camera(C.Structure):
    _fields_ = [("kind", C.c_uint32), ("width", C.c_uint32), ("height", C.c_uint32),
                ("reserved", C.c_uint32)] + [(k, C.c_double) for k in
                                             ("fx", "fy", "cx", "cy", "half_width", "half_height")] + [
                   ("c2w", C.c_double * 12)]


class PlanDesc(C.Structure):
    _fields_ = [("next", C.c_void_p), ("backend", C.c_uint32), ("precision", C.c_uint32),
                ("camera", Camera), ("aabb_min", C.c_double * 3), ("aabb_max", C.c_double * 3),
                ("near_t", C.c_double), ("far_t", C.c_double), ("dt", C.c_double),
                ("early_stop", C.c_double), ("background", C.c_double * 3),
                ("max_steps", C.c_uint32), ("sampling", C.c_uint32), ("seed", C.c_uint32),
                ("trans_path", C.c_uint32)]


class Rays(C.Structure):
    _fields_ = [("next", C.c_void_p), ("count", C.c_uint64)] + [
        (k, Tensor) for k in ("o", "d", "t0", "t1", "pixel")]


class Samp(C.Structure):
    _fields_ = [("next", C.c_void_p), ("capacity", C.c_uint64), ("count", C.c_uint64)] + [
        (k, Tensor) for k in ("off", "flags", "ray_id", "t", "dt", "sigma", "color")]


class Intl(C.Structure):
    _fields_ = [("next", C.c_void_p)] + [
        (k, Tensor) for k in ("rgb", "trans", "logtrans", "depth", "opacity", "nsamples",
                              "flags", "alpha", "log_t")]


class Img(C.Structure):
    _fields_ = [("next", C.c_void_p)] + [
        (k, Tensor) for k in ("rgb", "trans", "logtrans", "depth", "opacity", "hit", "nsamples")]


def view(a):
    """An hp_tensor over numpy array `a` (which must outlive the call)."""
    t = Tensor()
    t.data = a.ctypes.data
    t.dtype = HP_DTYPE[a.dtype]
    t.ndim = a.ndim
    for i in range(a.ndim):
        t.shape[i] = a.shape[i]
        t.stride[i] = a.strides[i] // a.itemsize
    return t


class Lib:
    def __init__(self, path):
        self.lib = C.CDLL(path)
        self.lib.hp_ctx_last_error.restype = C.c_char_p
        self.ctx = C.c_void_p()
        self.check(self.lib.hp_ctx_create(C.c_uint32(HP_ABI_VERSION), C.byref(self.ctx)))

    def check(self, status):
        if status != HP_OK:
            msg = self.lib.hp_ctx_last_error(self.ctx).decode()
            raise RuntimeError(f"hotpath status {status}: {msg}")

    def workspace(self, plan, stage, n, m):
        size = C.c_size_t()
        self.check(self.lib.hp_workspace_size(plan, C.c_uint32(stage), C.c_uint64(n),
                                              C.c_uint64(m), C.byref(size)))
        return np.zeros(max(size.value, 1), np.uint8)


def render_vol_gaussian(hp, dtype=np.float32):
    lib = hp.lib
    w = h = 64
    desc = PlanDesc()
    hp.check(lib.hp_plan_desc_default(C.byref(desc)))
    vec = C.c_double * 3
    hp.check(lib.hp_camera_pinhole_look_at(vec(0, 0, 3), vec(0, 0, 0), vec(0, 1, 0),
                                           C.c_double(40.0), C.c_uint32(w), C.c_uint32(h),
                                           C.byref(desc.camera)))
    desc.precision = HP_DTYPE[np.dtype(dtype)]
    plan = C.c_void_p()
    hp.check(lib.hp_plan_create(hp.ctx, C.byref(desc), C.byref(plan)))
    fs, fc = C.c_void_p(), C.c_void_p()
    params = (C.c_double * 5)(20, 0, 0, 0, 0.3)
    hp.check(lib.hp_field_create_analytic(hp.ctx, C.c_uint32(HP_ANALYTIC_GAUSSIAN), params,
                                          C.c_size_t(5), C.byref(fs)))
    hp.check(lib.hp_field_create_color_constant(hp.ctx, vec(1, 0.5, 0.25), C.byref(fc)))

    n = w * h
    ra = {"o": np.zeros((n, 3), dtype), "d": np.zeros((n, 3), dtype), "t0": np.zeros(n, dtype),
          "t1": np.zeros(n, dtype), "pixel": np.zeros(n, np.uint32)}
    rays = Rays(count=n, **{k: view(v) for k, v in ra.items()})
    ws = hp.workspace(plan, HP_STAGE_RAY, n, 0)
    hp.check(lib.hp_ray(plan, None, C.byref(rays), C.c_void_p(ws.ctypes.data), C.c_size_t(ws.size)))

    samp = Samp()  # capacity 0, no buffers: asks for the sample count
    ws = hp.workspace(plan, HP_STAGE_SAMP, n, n * desc.max_steps)
    hp.check(lib.hp_samp(plan, fs, fc, C.byref(rays), C.byref(samp), C.c_void_p(ws.ctypes.data),
                         C.c_size_t(ws.size)))
    m = samp.count
    sa = {"off": np.zeros(n + 1, np.uint32), "flags": np.zeros(n, np.uint8),
          "ray_id": np.zeros(m, np.uint32), "t": np.zeros(m, dtype), "dt": np.zeros(m, dtype),
          "sigma": np.zeros(m, dtype), "color": np.zeros((m, 3), dtype)}
    samp = Samp(capacity=m, count=0, **{k: view(v) for k, v in sa.items()})
    hp.check(lib.hp_samp(plan, fs, fc, C.byref(rays), C.byref(samp), C.c_void_p(ws.ctypes.data),
                         C.c_size_t(ws.size)))

    ia = {"rgb": np.zeros((n, 3), dtype), "trans": np.zeros(n, dtype),
          "logtrans": np.zeros(n, dtype), "depth": np.zeros(n, dtype),
          "opacity": np.zeros(n, dtype), "nsamples": np.zeros(n, np.int32),
          "flags": np.zeros(n, np.uint8), "alpha": np.zeros(m, dtype), "log_t": np.zeros(m, dtype)}
    intl = Intl(**{k: view(v) for k, v in ia.items()})
    ws = hp.workspace(plan, HP_STAGE_INT, n, m)
    hp.check(lib.hp_int(plan, C.byref(samp), C.byref(intl), C.c_void_p(ws.ctypes.data), C.c_size_t(ws.size)))

    rgb = np.zeros((h, w, 3), dtype)
    img = Img(rgb=view(rgb))  # the other image tensors stay empty: not written
    hp.check(lib.hp_img(plan, C.byref(intl), C.byref(rays), C.byref(img), None, C.c_size_t(0)))

    lib.hp_field_destroy(fs)
    lib.hp_field_destroy(fc)
    lib.hp_plan_destroy(plan)
    return rgb, m


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lib", required=True, help="path of libhotpath_capi.so")
    ap.add_argument("--compare", help="an rgb.npy to compare with, byte for byte")
    ap.add_argument("--out", help="where to save our rgb.npy")
    a = ap.parse_args()
    hp = Lib(a.lib)
    rgb, m = render_vol_gaussian(hp)
    print(f"vol_gaussian 64x64 f32: {m} samples, rgb mean {rgb.mean():.6f}")
    if a.out:
        np.save(a.out, rgb)
    if a.compare:
        ref = np.load(a.compare)
        if ref.dtype == rgb.dtype and ref.shape == rgb.shape and ref.tobytes() == rgb.tobytes():
            print(f"bit-identical to {a.compare}")
        else:
            diff = np.abs(ref.astype(np.float64) - rgb.astype(np.float64)).max()
            print(f"differs from {a.compare}: max |diff| {diff}")
            return 1
    hp.lib.hp_ctx_destroy(hp.ctx)
    return 0


if __name__ == "__main__":
    sys.exit(main())
