#!/usr/bin/env bash
# Resolve requirements/<distro>.in and write the pinned lock file requirements/<distro>.lock.
# The ROS wheels' metadata names (e.g. "action_msgs") differ from their PyPI project names
# ("ros-action-msgs"), so `pip freeze` output cannot be installed again; the names are taken
# from the resolved wheel file names in pip's installation report instead.
set -euo pipefail
cd "$(dirname "$0")/.."
distro="${SOFTSNAP_ROS_DISTRO:-jazzy}"
python="${PYTHON:-python3}"
report="$(mktemp)"
trap 'rm -f "$report"' EXIT
"$python" -m pip install --quiet --disable-pip-version-check --dry-run --ignore-installed \
  --report "$report" -r "requirements/$distro.in" 2> >(grep -v 'is ignored: it is neither' >&2)
"$python" - "$report" "requirements/$distro.lock" "$distro" <<'PY'
import json, sys, urllib.parse
report, out, distro = sys.argv[1:]
pins = set()
for item in json.load(open(report))['install']:
    filename = urllib.parse.unquote(item['download_info']['url'].rsplit('/', 1)[-1])
    if filename.endswith('.whl'):
        name, version = filename.split('-')[:2]
    else:  # sdist: name-version.tar.gz
        name, version = filename.rsplit('.tar.gz', 1)[0].rsplit('-', 1)
    pins.add(f"{name.replace('_', '-').lower()}=={version}")
with open(out, 'w') as f:
    f.write(f'# Pinned versions resolved from requirements/{distro}.in '
            '(regenerate: scripts/lock_requirements.sh).\n')
    f.write('\n'.join(sorted(pins)) + '\n')
print(f'wrote {out}: {len(pins)} pins')
PY
