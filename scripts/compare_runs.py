#!/usr/bin/env python3
"""Holds two `hpjudge run` output folders against each other (issue 12: a
refactor must not change a number).

    scripts/compare_runs.py BASE_OUT NEW_OUT

Checks, per case and backend of BASE_OUT/scoreboard.json: the same verdict,
the same output tensors (names, dtypes, shapes), every check's value equal
unless its metric is a time or a rate (wall, cpu seconds, per second,
speedup), and every `.npy` artifact byte-identical (except VARYING below and
the files named in --allow). Prints each difference; exit 1 on any.
"""
import argparse
import json
import os
import re
import sys

# Metrics measured in seconds or per second: they may differ between runs.
TIMED = re.compile(r"(wall|_s$|per_s|time_s|cpu_s)")
# Artifacts that differ between any two runs: measured times (and the plot
# drawn from them), and the self-test's deliberately nondeterministic output.
VARYING = [
    r"vol_dt_sweep_[^/]*/[^/]*/(time_f32|time_f64|plot_rgb)\.npy$",
    r"selftest_nondeterministic_run_fails/",
    r"selftest_plant_equal_count_fails/",
]


def load(out):
    with open(os.path.join(out, "scoreboard.json")) as f:
        b = json.load(f)
    return {(c["id"], r["backend"]): (c, r) for c in b["cases"] for r in c["results"]}


def npys(out):
    found = {}
    for d, _, files in os.walk(out):
        for n in files:
            if n.endswith(".npy"):
                p = os.path.join(d, n)
                found[os.path.relpath(p, out)] = p
    return found


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("base")
    ap.add_argument("new")
    ap.add_argument("--allow", action="append", default=[],
                    help="regex of artifact paths whose bytes may differ")
    a = ap.parse_args()
    bad = []
    base, new = load(a.base), load(a.new)
    for k in sorted(set(base) | set(new)):
        if k not in new or k not in base:
            bad.append(f"{k}: only in {'base' if k in base else 'new'}")
            continue
        (_, rb), (_, rn) = base[k], new[k]
        if rb["verdict"] != rn["verdict"]:
            bad.append(f"{k}: verdict {rb['verdict']} -> {rn['verdict']} ({rn['reason']})")
        if rb.get("tensors") != rn.get("tensors"):
            bad.append(f"{k}: tensors {rb.get('tensors')} -> {rn.get('tensors')}")
        cb, cn = rb.get("checks", []), rn.get("checks", [])
        if len(cb) != len(cn):
            bad.append(f"{k}: {len(cb)} checks -> {len(cn)}")
        for x, y in zip(cb, cn):
            if x["metric"] != y["metric"] or x["passed"] != y["passed"]:
                bad.append(f"{k}: check {x['metric']} {x['passed']} -> {y['metric']} {y['passed']}")
            elif x["value"] != y["value"] and not TIMED.search(x["metric"]):
                bad.append(f"{k}: check {x['metric']} value {x['value']} -> {y['value']}")
    allow = [re.compile(r) for r in VARYING + a.allow]
    fb, fn = npys(a.base), npys(a.new)
    same = 0
    for rel in sorted(set(fb) | set(fn)):
        if rel not in fb or rel not in fn:
            bad.append(f"{rel}: only in {'base' if rel in fb else 'new'}")
            continue
        with open(fb[rel], "rb") as f1, open(fn[rel], "rb") as f2:
            if f1.read() == f2.read():
                same += 1
            elif not any(r.search(rel) for r in allow):
                bad.append(f"{rel}: bytes differ")
    for line in bad:
        print(line)
    print(f"{len(base)} case results, {same}/{len(fb)} .npy byte-identical, {len(bad)} differences")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
