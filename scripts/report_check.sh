#!/usr/bin/env bash
# Checks a run's HTML report in headless Chromium (issue 21):
#   scripts/report_check.sh OUT_DIR [REPORT_HTML]
# writes OUT_DIR/report.html with `hpjudge report` (unless REPORT_HTML is
# given), then requires that
#   1. the page loads with no console error: no "Uncaught"/console.error line
#      in Chromium's log (--enable-logging=stderr), and no `js-error`
#      element in the DOM (the page's own error catcher, report/page.rs);
#   2. its script ran to the end (`data-report-ready="1"` on <body>);
#   3. the DOM (--dump-dom) lists every case id of OUT_DIR/scoreboard.json;
# and writes a screenshot, OUT_DIR/report.png (a CI artifact).
# Installs Debian's `chromium` when missing (as root), like lavapipe.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:?usage: scripts/report_check.sh OUT_DIR [REPORT_HTML]}"
hpjudge="${CARGO_TARGET_DIR:-target}/release/hpjudge"
page="${2:-$out/report.html}"
if [ -z "${2:-}" ]; then
    "$hpjudge" report "$out" -o "$page" >/dev/null
fi

browser=""
for b in chromium chromium-browser google-chrome; do
    if command -v "$b" >/dev/null 2>&1; then browser="$b"; break; fi
done
if [ -z "$browser" ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "installing chromium (Debian package) for the report check" >&2
        apt-get update -qq >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >&2
        browser=chromium
    else
        echo "report check: no chromium and not root to install it" >&2
        exit 1
    fi
fi

profile="$(mktemp -d)"
trap 'rm -rf "$profile"' EXIT
url="file://$(cd "$(dirname "$page")" && pwd)/$(basename "$page")"
flags=(--headless --no-sandbox --disable-gpu --disable-quic --no-first-run
    --disable-background-networking --disable-component-update --disable-sync
    --user-data-dir="$profile" --enable-logging=stderr --v=0)

timeout 120 "$browser" "${flags[@]}" --dump-dom "$url" >"$profile/dom.html" 2>"$profile/log.txt" || {
    echo "report check: chromium failed on $url" >&2
    tail -20 "$profile/log.txt" >&2
    exit 1
}
fail=0
if grep -E 'CONSOLE.*(Uncaught|Error)|console\.error' "$profile/log.txt" >&2; then
    echo "report check: console errors above" >&2
    fail=1
fi
if grep -o '<pre class="js-error">[^<]*' "$profile/dom.html" >&2; then
    echo "report check: the page recorded script errors (above)" >&2
    fail=1
fi
if ! grep -q 'data-report-ready="1"' "$profile/dom.html"; then
    echo "report check: the page's script did not run to its end" >&2
    fail=1
fi
# Every case id of the scoreboard must be a data-case of the DOM.
python3 - "$out/scoreboard.json" "$profile/dom.html" <<'EOF' || fail=1
import html, json, re, sys
board = json.load(open(sys.argv[1]))
dom = open(sys.argv[2], encoding="utf-8").read()
shown = {html.unescape(m) for m in re.findall(r'data-case="([^"]*)"', dom)}
want = {c["id"] for c in board["cases"]}
missing = sorted(want - shown)
if missing:
    print(f"report check: {len(missing)} of {len(want)} cases missing from the DOM: {missing[:10]}", file=sys.stderr)
    sys.exit(1)
print(f"report check: all {len(want)} cases in the DOM", file=sys.stderr)
EOF
timeout 120 "$browser" "${flags[@]}" --hide-scrollbars --window-size=1280,2400 \
    --screenshot="$out/report.png" "$url" >/dev/null 2>&1 || {
    echo "report check: no screenshot" >&2
    fail=1
}
[ -s "$out/report.png" ] || fail=1
if [ "$fail" = 0 ]; then
    echo "report check: ok ($page, screenshot $out/report.png)"
fi
exit "$fail"
