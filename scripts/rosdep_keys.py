#!/usr/bin/env python3
"""Regenerate requirements/rosdep/*.txt, the rosdep keys test/tools/test_rosdep_keys.py
checks every package.xml against, from a checkout of the ros/rosdistro repository.

Usage: python3 scripts/rosdep_keys.py /path/to/rosdistro
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

OUT = Path(__file__).resolve().parents[1] / 'requirements' / 'rosdep'
DISTROS = ('jazzy', 'kilted')
REGENERATE = '# Regenerate: scripts/rosdep_keys.py <rosdistro checkout>\n'


def main(rosdistro: str) -> int:
    root = Path(rosdistro)
    commit, date = subprocess.run(['git', '-C', str(root), 'log', '-1', '--format=%H %cs'],
                                  capture_output=True, text=True, check=True).stdout.split()
    source = f'ros/rosdistro at commit {commit} ({date})'
    keys = set()
    for name in ('base.yaml', 'python.yaml'):
        rules = yaml.safe_load((root / 'rosdep' / name).read_text())
        # a key rosdep can install on Ubuntu (the ROS 2 platform) or Debian
        keys |= {k for k, v in rules.items() if isinstance(v, dict) and ('ubuntu' in v or 'debian' in v)}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / 'system-keys.txt').write_text(
        '# rosdep keys that resolve on Ubuntu or Debian: every key of rosdep/base.yaml and\n'
        f'# rosdep/python.yaml with an ubuntu or debian rule, from {source}.\n' + REGENERATE
        + '\n'.join(sorted(keys)) + '\n')
    for distro in DISTROS:
        release = yaml.safe_load((root / distro / 'distribution.yaml').read_text())
        packages = set()
        for name, repo in release['repositories'].items():
            if repo.get('release'):
                packages.update(repo['release'].get('packages', [name]))
        (OUT / f'{distro}-packages.txt').write_text(
            f'# ROS packages released for {distro} (rosdep keys of ROS packages): {distro}/'
            'distribution.yaml,\n# repositories.*.release.packages, from ' f'{source}.\n'
            + REGENERATE + '\n'.join(sorted(packages)) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main(*sys.argv[1:]))
