#!/usr/bin/env python3
"""Writes GOLDENS/rng/table_words.npy and table_floats.npy: the SCENES.md
random-number function over a grid of keys, computed here in plain Python
(independent of the Rust code under test). Run from the repository root.
The key grid must match the `rays_rng_table` case in TESTS/rays/manifest.yaml."""
import struct

M = 0xFFFFFFFF
SEEDS = [0, 1, 42, 4294967295]
PIXELS = [0, 1, 12345, 262143]
SAMPLES = [0, 7, 1023]
DIMS = [0, 1, 2, 63]


def pcg(v):
    s = (v * 747796405 + 2891336453) & M
    w = (((s >> ((s >> 28) + 4)) ^ s) * 277803737) & M
    return ((w >> 22) ^ w) & M


def rand(seed, pixel, sample, dim):
    return pcg(pcg(pcg(pcg(seed) ^ pixel) ^ sample) ^ dim)


def write_npy(path, descr, shape, data_bytes):
    header = "{'descr': '%s', 'fortran_order': False, 'shape': (%s), }" % (
        descr, ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else ""))
    pad = 64 - (10 + len(header) + 1) % 64
    header = header + " " * pad + "\n"
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode("latin1") + data_bytes)


words = [rand(s, p, k, d) for s in SEEDS for p in PIXELS for k in SAMPLES for d in DIMS]
floats = [(w >> 8) * 2.0 ** -24 for w in words]
shape = (len(SEEDS), len(PIXELS), len(SAMPLES), len(DIMS))
write_npy("GOLDENS/rng/table_words.npy", "<u4", shape, struct.pack("<%dI" % len(words), *words))
write_npy("GOLDENS/rng/table_floats.npy", "<f4", shape, struct.pack("<%df" % len(floats), *floats))
print("wrote", len(words), "values")
