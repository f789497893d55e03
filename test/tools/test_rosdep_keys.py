"""Every dependency of every package.xml resolves with rosdep on a ROS 2 install.

The keys are checked against lists taken from ros/rosdistro (the database rosdep reads;
requirements/rosdep/*.txt name the commit and scripts/rosdep_keys.py regenerates them): a
key is a package of this workspace, a ROS package released for both Jazzy and Kilted, or
a system key of rosdep/base.yaml or rosdep/python.yaml with an Ubuntu or Debian rule.
Python packages without a key belong in requirements/ros-install.txt instead.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
KEYS_DIR = REPO / 'requirements' / 'rosdep'
DEPEND_TAGS = ('depend', 'build_depend', 'build_export_depend', 'buildtool_depend',
               'buildtool_export_depend', 'exec_depend', 'test_depend', 'doc_depend')
PACKAGE_XMLS = sorted(REPO.glob('src/*/package.xml'))


def _keys(name: str) -> set[str]:
    lines = (KEYS_DIR / name).read_text().splitlines()
    return {line.strip() for line in lines if line.strip() and not line.startswith('#')}


SYSTEM = _keys('system-keys.txt')
ROS = _keys('jazzy-packages.txt') & _keys('kilted-packages.txt')
WORKSPACE = {ET.parse(p).getroot().findtext('name') for p in PACKAGE_XMLS}


def test_the_key_lists_are_the_real_database():
    # Spot checks against what rosdep is known to have (and not to have).
    assert {'python3-numpy', 'python3-mujoco-pip', 'python3-rosbags-pip'} <= SYSTEM
    assert {'rclpy', 'tf2_msgs', 'rviz2', 'robot_state_publisher', 'launch_ros'} <= ROS
    assert not {'python3-rerun-sdk-pip', 'python3-mpmath', 'chromium'} & (SYSTEM | ROS)
    assert len(SYSTEM) > 1500 and len(ROS) > 1000
    assert all('ros/rosdistro at commit' in (KEYS_DIR / f).read_text().splitlines()[1]
               for f in ('system-keys.txt', 'jazzy-packages.txt', 'kilted-packages.txt'))


@pytest.mark.parametrize('package_xml', PACKAGE_XMLS, ids=lambda p: p.parent.name)
def test_every_dependency_is_a_rosdep_key(package_xml):
    root = ET.parse(package_xml).getroot()
    keys = [(tag, el.text.strip()) for tag in DEPEND_TAGS for el in root.iter(tag)]
    assert keys, f'{package_xml} declares no dependency'
    unknown = [f'<{tag}>{key}</{tag}>' for tag, key in keys
               if key not in WORKSPACE | ROS | SYSTEM]
    assert not unknown, (
        f'{package_xml.relative_to(REPO)}: not rosdep keys (rosdistro, '
        f'requirements/rosdep/): {unknown}; a pip-only Python package goes in '
        f'requirements/ros-install.txt')


def test_the_ros_install_extras_are_pinned_as_in_the_lock_file():
    lock = {line.split('==')[0].lower(): line.split('==')[1].split()[0]
            for line in (REPO / 'requirements' / 'jazzy.lock').read_text().splitlines()
            if '==' in line and not line.startswith('#')}
    extras = [line.split('#')[0].strip() for line in
              (REPO / 'requirements' / 'ros-install.txt').read_text().splitlines()]
    pins = dict(e.split('==') for e in extras if e)
    assert 'rerun-sdk' in pins
    assert {name: version for name, version in pins.items()
            if lock.get(name.lower()) != version} == {}
