#!/usr/bin/env bash
# Makes sure this machine has a Vulkan adapter for the GPU cases (issue 5).
#
#   scripts/gpu_setup.sh [HPJUDGE]      # run it, or
#   source scripts/gpu_setup.sh; hp_gpu_setup [HPJUDGE]
#
# HPJUDGE is the hpjudge binary (default target/release/hpjudge, or
# $CARGO_TARGET_DIR/release/hpjudge). It asks `hpjudge info --json` for an
# adapter (any `"backend": "vulkan" | "metal" | "dx12"` entry); when there is
# none and apt-get is usable (root, or password-less sudo), it installs Mesa's
# software Vulkan driver (lavapipe: mesa-vulkan-drivers libvulkan1) and asks
# again. Exit status: 0 with an adapter, 1 without one (the caller decides:
# `hpjudge run --require-gpu` then fails every GPU case instead of skipping).
# Also exports XDG_RUNTIME_DIR when unset (Mesa's window-system code warns
# without it on every process start).

hp_gpu_has_adapter() {
    "$1" info --json 2>/dev/null | grep -Eq '"backend"[[:space:]]*:[[:space:]]*"(vulkan|metal|dx12)"'
}

hp_gpu_setup() {
    local hpj="${1:-${CARGO_TARGET_DIR:-target}/release/hpjudge}"
    if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
        XDG_RUNTIME_DIR="$(mktemp -d /tmp/hp-xdg.XXXXXX)"
        export XDG_RUNTIME_DIR
    fi
    if [ ! -x "$hpj" ]; then
        echo "gpu_setup: $hpj not built (cargo build --release first)" >&2
        return 1
    fi
    if hp_gpu_has_adapter "$hpj"; then
        echo "gpu_setup: GPU adapter present" >&2
        return 0
    fi
    local sudo=""
    if [ "$(id -u)" != 0 ]; then
        if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
            sudo="sudo -n"
        else
            echo "gpu_setup: no GPU adapter, and apt-get needs root: install mesa-vulkan-drivers libvulkan1" >&2
            return 1
        fi
    fi
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "gpu_setup: no GPU adapter and no apt-get: install a Vulkan driver (Mesa lavapipe)" >&2
        return 1
    fi
    echo "gpu_setup: no GPU adapter; installing lavapipe (mesa-vulkan-drivers libvulkan1)" >&2
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2 &&
        $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >&2 ||
        { echo "gpu_setup: apt-get failed" >&2; return 1; }
    if hp_gpu_has_adapter "$hpj"; then
        echo "gpu_setup: lavapipe installed, adapter present" >&2
        return 0
    fi
    echo "gpu_setup: still no adapter after installing lavapipe" >&2
    return 1
}

# Run when executed, not when sourced.
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    set -u
    hp_gpu_setup "$@"
fi
