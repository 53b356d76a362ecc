#!/usr/bin/env python3
"""Compare two `hpjudge run --out` dirs: per-case verdicts and checks (scoreboard.json) and the bytes of every .npy (issue 12 "no numeric change").

Usage: scripts/compare_out_dirs.py OUT_BEFORE OUT_AFTER  (exit 1 when anything differs)"""
import json, os, sys, hashlib
a, b = sys.argv[1], sys.argv[2]
def verdicts(d):
    s = json.load(open(os.path.join(d, "scoreboard.json")))
    out = {}
    for c in s["cases"]:
        for r in c["results"]:
            out[(c["id"], r["backend"])] = (r["verdict"], [(k.get("name"), k.get("verdict", k.get("pass"))) for k in r.get("checks") or [] if isinstance(k, dict)])
    return out
def npys(d):
    r = {}
    for root, _, files in os.walk(d):
        for f in files:
            if f.endswith(".npy"):
                p = os.path.join(root, f)
                r[os.path.relpath(p, d)] = hashlib.sha256(open(p, "rb").read()).hexdigest()
    return r
va, vb = verdicts(a), verdicts(b)
diff_v = [(k, va.get(k), vb.get(k)) for k in sorted(set(va) | set(vb), key=str) if va.get(k) != vb.get(k)]
na, nb = npys(a), npys(b)
diff_n = [k for k in sorted(set(na) | set(nb)) if na.get(k) != nb.get(k)]
print(f"verdicts: {len(va)} vs {len(vb)}, {len(diff_v)} differ")
for d in diff_v[:20]: print("  ", d)
print(f"npy files: {len(na)} vs {len(nb)}, {len(diff_n)} differ in bytes")
for d in diff_n[:20]: print("  ", d)
sys.exit(1 if diff_v or diff_n else 0)
