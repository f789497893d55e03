"""The shipped RViz configurations: one per scene, up to date, showing what is published.

rviz2 is not on PyPI, so the files are checked as data: they are this project's
generator output, rviz2's YAML, with the fixed frame at the URDF's root and the displays
on the topics robot_state and model_node publish (with the QoS they publish with).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from softsnap_gaits import launching, rviz_config
from softsnap_model.robot_description import describe_robot
from softsnap_model.scene import list_scenes, load_scene

REPO = Path(__file__).resolve().parents[2]
RVIZ = REPO / 'src' / 'softsnap_gaits' / 'rviz'


@pytest.mark.parametrize('scene_name', list_scenes())
def test_each_scene_ships_its_current_config(scene_name):
    path = RVIZ / f'{scene_name}.rviz'
    assert path.read_text() == rviz_config.config_text(scene_name), (
        'run: .venv/bin/python -m softsnap_gaits.rviz_config')
    config = yaml.safe_load(path.read_text())
    manager = config['Visualization Manager']
    urdf = ET.fromstring(describe_robot(load_scene(scene_name)).urdf)
    children = {j.find('child').get('link') for j in urdf.findall('joint')}
    roots = {link.get('name') for link in urdf.findall('link')} - children
    assert {manager['Global Options']['Fixed Frame']} == roots
    displays = {d['Class'].split('/')[-1]: d for d in manager['Displays']}
    model = displays['RobotModel']['Description Topic']
    assert (model['Value'], model['Durability Policy']) == ('/robot_description', 'Transient Local')
    assert displays['MarkerArray']['Topic']['Value'] == f'/{scene_name}/model/markers'
    assert 'TF' in displays


def test_rviz_is_a_launch_argument_off_by_default():
    assert launching.LAUNCH_ARGUMENTS['rviz'][0] == 'false'


def test_the_launch_files_rviz_opens_the_installed_config():
    kwargs = launching.rviz_action_kwargs('snake')
    assert (kwargs['package'], kwargs['executable']) == ('rviz2', 'rviz2')
    flag, path = kwargs['arguments']
    assert flag == '-d' and Path(path).read_text() == rviz_config.config_text('snake')
