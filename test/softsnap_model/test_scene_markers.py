"""The scene's optional per-module `markers: {tag_id: N}` (what the camera identifies a module by)."""
from __future__ import annotations

import pytest
import yaml

from softsnap_model.scene import SceneError, find_scene, load_scene


def test_brittle_star_declares_one_tag_per_module_and_other_scenes_none():
    assert [m.tag_id for m in load_scene('brittle_star').modules] == [0, 1, 2, 3, 4]
    assert all(m.tag_id is None for m in load_scene('snake').modules)


@pytest.mark.parametrize('markers,words', [
    ({'tag_id': 0}, 'a tag id no other module has'),     # modules[0] already has 0
    ({'tag_id': -1}, 'an integer from 0 to 999'),
    ({'tag_id': 'a'}, 'an integer from 0 to 999'),
    ({'tag': 3}, 'known keys'),
    ('7', 'mapping'),
])
def test_bad_markers_refused_with_key_and_reason(tmp_path, markers, words):
    data = yaml.safe_load(find_scene('brittle_star').read_text())
    data['modules'][1]['markers'] = markers
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert 'modules[1].markers' in str(err.value) and words in str(err.value)


def test_markers_are_optional(tmp_path):
    data = yaml.safe_load(find_scene('brittle_star').read_text())
    for m in data['modules']:
        m.pop('markers')
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    assert [m.tag_id for m in load_scene(path).modules] == [None] * 5
