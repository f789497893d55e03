#!/usr/bin/env bash
# Re-resolve requirements/<distro>.in in a scratch venv and write the pinned lock file.
set -euo pipefail
cd "$(dirname "$0")/.."
distro="${SOFTSNAP_ROS_DISTRO:-jazzy}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"${PYTHON:-python3}" -m venv "$tmp/venv"
"$tmp/venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "requirements/$distro.in"
{ echo "# Pinned versions resolved from requirements/$distro.in (regenerate: scripts/lock_requirements.sh)."
  "$tmp/venv/bin/pip" freeze --exclude-editable | sort; } > "requirements/$distro.lock"
echo "wrote requirements/$distro.lock"
