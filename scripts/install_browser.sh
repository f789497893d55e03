#!/usr/bin/env bash
# Make a headless Chromium available for the rerun web viewer screenshot test and print
# the path of its executable on the last line of stdout. Idempotent: a second run only
# finds the browser again.
#
# Order of attempts:
#   1. a chromium already on PATH (or SOFTSNAP_CHROMIUM pointing at an executable);
#   2. one unpacked earlier into build/chromium/ by step 4;
#   3. as root: `apt-get install -y chromium` (Debian's package, with its dependencies);
#   4. without root: `apt-get download` of chromium and chromium-common, unpacked with
#      `dpkg -x` into build/chromium/ (works when the shared libraries it needs are
#      already on the machine, which is usual for a desktop or a CI image with X libs).
# Exit status 0 with the path printed, or 1 with the reason on stderr.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
unpack_dir="$root/build/chromium"
log() { printf '[install_browser] %s\n' "$*" >&2; }

works() {
  # A browser counts only if it starts far enough to print its version.
  [ -n "${1:-}" ] && [ -x "$1" ] && "$1" --version >/dev/null 2>&1
}

found() { printf '%s\n' "$1"; exit 0; }

if [ -n "${SOFTSNAP_CHROMIUM:-}" ] && works "$SOFTSNAP_CHROMIUM"; then found "$SOFTSNAP_CHROMIUM"; fi
for name in chromium chromium-browser; do
  path="$(command -v "$name" || true)"
  if works "$path"; then found "$path"; fi
done
if works "$unpack_dir/usr/bin/chromium"; then found "$unpack_dir/usr/bin/chromium"; fi

if ! command -v apt-get >/dev/null 2>&1; then
  log "no chromium found and no apt-get on this machine to install one"
  exit 1
fi

# One install at a time per checkout (tests of several engineers may start together).
mkdir -p "$root/build"
exec 8>"$root/build/.install_browser.lock"
flock 8
# Someone else may have finished the install while this run waited for the lock.
path="$(command -v chromium || true)"
if works "$path"; then found "$path"; fi
if works "$unpack_dir/usr/bin/chromium"; then found "$unpack_dir/usr/bin/chromium"; fi

if [ "$(id -u)" = 0 ]; then
  log "installing Debian package chromium"
  if ! apt-get install -y --no-install-recommends chromium >&2; then
    log "apt-get install failed; refreshing the package lists once and retrying"
    apt-get update >&2
    apt-get install -y --no-install-recommends chromium >&2
  fi
  path="$(command -v chromium || true)"
  if works "$path"; then found "$path"; fi
  log "chromium installed but does not start"
  exit 1
fi

log "not root: downloading chromium and chromium-common into $unpack_dir"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && apt-get download chromium chromium-common >&2) || {
  log "apt-get download failed (package lists missing or no access to the Debian archive)"
  exit 1
}
mkdir -p "$unpack_dir"
for deb in "$tmp"/*.deb; do dpkg -x "$deb" "$unpack_dir"; done
if works "$unpack_dir/usr/bin/chromium"; then found "$unpack_dir/usr/bin/chromium"; fi
log "unpacked chromium does not start; missing shared libraries:"
ldd "$unpack_dir/usr/lib/chromium/chromium" 2>/dev/null | grep 'not found' >&2 || true
exit 1
