#!/usr/bin/env bash
# Runs hpjudge on a lent real GPU (the tool library's `device` machine: an
# NVIDIA Hopper, H100 or H200, with no Rust and no registry). Build here
# first, then carry the stripped binary and the Vulkan loader:
#
#   cargo build --release --bin hpjudge
#   mkdir -p .dev && cp target/release/hpjudge .dev/ && strip .dev/hpjudge
#   cp /usr/share/glmark2/models/bunny.obj .dev/      # the bunny cases
#   (.gl/: the loader .debs the device README names; .dev and .gl are in
#   .git/info/exclude)
#   device run, carry [.gl, .dev]:  bash scripts/device_gpu.sh STAGE...
#
# Stages, in the order given:
#   info    hpjudge info (the adapter must be the NVIDIA one)
#   suite   the whole manifest with --require-gpu (default profile)
#   perf:F  hpjudge perf --filter F (repeatable)
#   render  hpjudge render of the Cornell box on the GPU at 512x512, 64 spp
#   cases:F the GPU cases whose id contains F, with --dump-failing; the
#           failing ones' tensors come back as $OUT/cases_F.tar.gz
# Device time is short (15 minutes a task as of 2026-11-30, start-up
# included, about 35 s a start on the H200; a command at most 10 minutes) and
# the whole suite took 523 s on the H100: run `suite` alone or not at all.
# Every GPU case (`cases:`, 84-108 s on the H200) and the voxel table
# (`perf:voxels_gpu_`, about 130 s, most of it building the Menger trees)
# fit one call; the perf stages also give the tiled thread order's gain over
# rows (`*_gpu_coherent_tiles_over_rows`) and the beam pre-pass's over casts
# from `near` (`*_gpu_coherent_beam_over_plain`, `*_gpu_coherent_beam_ran` 1
# where the adapter has f64). The twenty-fourth session's calls:
#   info perf:voxels_gpu_menger_d10 perf:voxels_gpu_sphere perf:voxels_gpu_points perf:voxels_gpu_bunny cases: render
# Perf and info output lands in $OUT/results.tar.gz; the log is $OUT/log.txt; the last
# lines printed are a summary (suite verdicts, perf metrics named by
# HP_PERF_KEYS, a regex; default every metric). HP_DEADLINE_S (seconds from
# the script's start) bounds the run: a stage that would start later is
# skipped, one running then is stopped, and what came before still comes back.
set -uo pipefail
cd "$(dirname "$0")/.."
: "${OUT:=/tmp/hp-device-out}"
mkdir -p "$OUT"
res=/tmp/hp-results
rm -rf "$res" && mkdir -p "$res"
exec > >(tee -a "$OUT/log.txt") 2>&1

for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
export WGPU_BACKEND=vulkan XDG_RUNTIME_DIR=/tmp
# The perf workers' worker.log (in results.tar.gz) then says how many casts
# each timed submission held.
export HPJUDGE_LOG="${HPJUDGE_LOG:-warn,hotpath::judge::measure=info}"
mkdir -p /usr/share/glmark2/models
[ -f .dev/bunny.obj ] && cp .dev/bunny.obj /usr/share/glmark2/models/
hpj=.dev/hpjudge
nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.mem,temperature.gpu --format=csv

summary=()
start=$(date +%s)
deadline=${HP_DEADLINE_S:-100000}
for stage in "$@"; do
    t0=$(date +%s.%N)
    rem=$((deadline - ($(date +%s) - start)))
    if [ "$rem" -le 5 ]; then
        echo "== stage $stage: skipped (HP_DEADLINE_S=$deadline reached)"
        summary+=("$stage: skipped at the deadline")
        continue
    fi
    tmo=(timeout "$rem")
    case "$stage" in
        info)
            "${tmo[@]}" "$hpj" info | tee "$res/info.txt"
            ;;
        suite)
            "${tmo[@]}" "$hpj" run TESTS/manifest.yaml --out "$res/suite" --require-gpu | tee "$res/suite.log"
            summary+=("suite: $(tail -n 1 "$res/suite.log")")
            grep -E "FAIL|ERROR" "$res/suite.log" | head -40
            ;;
        perf:*)
            f="${stage#perf:}"
            # The SM clock every 100 ms while the stage runs: were the GPU's
            # millisecond-long casts timed at boost clocks?
            nvidia-smi --query-gpu=timestamp,clocks.sm,utilization.gpu --format=csv,noheader,nounits \
                -lms 100 >"$res/clocks_$f.csv" 2>/dev/null &
            smi=$!
            # Why the clock was where it was (bit 0x1 GPU idle, 0x4 power
            # cap, 0x8 / 0x20 / 0x40 / 0x80 slowdowns: NVML nvmlClocksEventReasons),
            # in a sampler of its own so a driver that names the field
            # otherwise loses only this file.
            nvidia-smi --query-gpu=timestamp,clocks_event_reasons.active --format=csv,noheader \
                -lms 100 >"$res/reasons_$f.csv" 2>&1 &
            smi_reasons=$!
            "${tmo[@]}" "$hpj" perf --filter "$f" --out "$res/perf_$f" --json >"$res/perf_$f.json"
            kill "$smi" "$smi_reasons" 2>/dev/null
            python3 - "$res/reasons_$f.csv" <<'EOF' | tee -a "$res/perf_summary.txt"
import collections, sys
text = open(sys.argv[1]).read()
seen = collections.Counter(l.split(",")[-1].strip() for l in text.splitlines() if "," in l)
print("clock event reasons, samples of each mask:", dict(seen) or text[:200].strip())
EOF
            python3 - "$res/clocks_$f.csv" <<'EOF' | tee -a "$res/perf_summary.txt"
import csv, sys
rows = [r for r in csv.reader(open(sys.argv[1])) if len(r) >= 3]
vals = []
for r in rows:
    try:
        vals.append((float(r[1]), float(r[2])))
    except ValueError:
        pass
busy = [m for m, u in vals if u > 0]
if vals:
    # The twenty-fourth session's H200 sat at its 345 MHz idle clock through
    # one-cast-at-a-time timing: say how much of the busy time was boosted.
    top = max(m for m, _ in vals)
    boosted = sum(m >= 0.9 * top for m in busy)
    print(f"SM clock MHz, {len(vals)} samples: {min(m for m, _ in vals):.0f}-{top:.0f}; "
          f"while busy ({len(busy)}): {min(busy, default=0):.0f}-{max(busy, default=0):.0f}, "
          f"{boosted} of them within 10% of {top:.0f}")
EOF
            python3 - "$res/perf_$f/perf.json" "${HP_PERF_KEYS:-.}" <<'EOF' | tee -a "$res/perf_summary.txt"
import json, re, sys
d = json.load(open(sys.argv[1]))
keys = re.compile(sys.argv[2])
for s in d.get("scenarios", []):
    for k, v in sorted(s.get("metrics", {}).items()):
        if keys.search(k):
            med = v.get("median", v) if isinstance(v, dict) else v
            print(f"{s.get('id')} {k} {med}")
EOF
            ;;
        cases:*)
            f="${stage#cases:}"
            "${tmo[@]}" "$hpj" run TESTS/manifest.yaml --backend gpu --filter "$f" --dump-failing \
                --out "/tmp/hp-cases/$f" --require-gpu | tee "$res/cases_$f.log"
            summary+=("cases $f: $(tail -n 1 "$res/cases_$f.log")")
            grep -E "^(FAIL|ERROR|TIMEOUT)" "$res/cases_$f.log" | head -40
            failing=$(grep -E "^(FAIL|ERROR|TIMEOUT)" "$res/cases_$f.log" | awk '{print $2}' | sort -u)
            if [ -n "$failing" ]; then
                # shellcheck disable=SC2086
                (cd "/tmp/hp-cases/$f" && tar -czf "$OUT/cases_$f.tar.gz" --exclude='*_key.npy' \
                    --exclude='*iters.npy' scoreboard.json $failing)
            fi
            ;;
        render)
            "${tmo[@]}" "$hpj" render TESTS/scenes/cornell_box.yaml --backend gpu --set spp=64 --out "$res/render" \
                2>&1 | tail -n 5
            ;;
        *)
            echo "unknown stage $stage" >&2
            ;;
    esac
    echo "== stage $stage: $(python3 -c "import sys; print(round($(date +%s.%N) - $t0, 1))") s"
done
tar -czf "$OUT/results.tar.gz" -C "$res" .
echo "== summary"
printf '%s\n' "${summary[@]}"
[ -f "$res/perf_summary.txt" ] && wc -l "$res/perf_summary.txt"
