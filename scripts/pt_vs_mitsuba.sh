#!/usr/bin/env bash
# The path tracer against Mitsuba 3 `llvm_ad_rgb` on the SCENES.md Cornell
# box (512x512, 64 spp, seed 1), interleaved ROUNDS times in one sitting:
# Mitsuba's warm render (scripts/mitsuba_cornell.py --repeat 2: the second
# render, wall and process CPU seconds) then ours with each CPU tracer
# (wavefront, packet, scalar: `hpjudge render`, wall and CPU seconds from
# GNU time). Equal error: our images are bit-identical across tracers and
# match Mitsuba's 64-spp RMSE at 62-64 spp (docs/PERF.md), so the CPU-second
# ratio at 64 spp is the equal-error time ratio up to that factor.
# SAMPLERS (default "independent multijitter") picks Mitsuba's samplers:
# multijitter was its lowest 64-spp RMSE in docs/PERF.md (fifth session), so
# the fair ratio is against that; TRACERS (default "wavefront packet scalar");
# OURS_SAMPLERS (default "independent") picks our `sampler:` (independent,
# sobol), each run with every tracer. Sobol's images differ from
# independent's, so its equal-error factor comes from its own RMSE
# (docs/PERF.md, sixth session).
#
#   pip install mitsuba==3.9.1        # + libLLVM 19 for the llvm variant
#   ROUNDS=2 bash scripts/pt_vs_mitsuba.sh [target/release/hpjudge]
set -euo pipefail
BIN=${1:-target/release/hpjudge}
ROUNDS=${ROUNDS:-2}
SIZE=${SIZE:-512}
SPP=${SPP:-64}
SAMPLERS=${SAMPLERS:-independent multijitter}
TRACERS=${TRACERS:-wavefront packet scalar}
OURS_SAMPLERS=${OURS_SAMPLERS:-independent}
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for r in $(seq "$ROUNDS"); do
  for smp in $SAMPLERS; do
    python3 scripts/mitsuba_cornell.py --spp "$SPP" --size "$SIZE" --seed 1 --repeat 2 \
      --sampler "$smp" --out "$out/mi.npy" | tail -1 | sed "s/^/round $r mitsuba $smp /"
  done
  for os in $OURS_SAMPLERS; do
    for tr in $TRACERS; do
      /usr/bin/time -f "%e %U %S" -o "$out/t" "$BIN" render TESTS/scenes/cornell_box.yaml \
        --set width="$SIZE" --set height="$SIZE" --set spp="$SPP" --set seed=1 \
        --set tracer="$tr" --set sampler.type="$os" --out "$out/$tr" >/dev/null 2>&1
      awk -v r="$r" -v tr="$tr" -v os="$os" '{printf "round %s ours %s %s: %.3f s wall, %.3f CPU-s\n", r, os, tr, $1, $2 + $3}' "$out/t"
    done
  done
done
