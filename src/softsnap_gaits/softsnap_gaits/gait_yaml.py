"""Write a gait into a scene file as a named gait, keeping the rest of the file as it is.

No ROS. :func:`write_scene_gait` inserts (or replaces) one entry of the scene's ``gaits:``
section as text, so the file's comments and layout survive, then loads the result with
the scene loader and builds the gait with :func:`softsnap_gaits.gaits.make_gait` (every
limit: contraction, reachability, winch speed) before it replaces the target file. A gait
the scene would refuse is never written: the error says why and the file is unchanged.
The written gait is an ordinary gait of an existing type, so ``gait_node`` and the demo
play it with no change (the scene format is unchanged).
"""
from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path
from typing import Mapping, Sequence

import yaml

__all__ = ['write_scene_gait', 'gait_block', 'GAIT_NAME_PATTERN']

#: A gait name the file can hold as a plain YAML key.
GAIT_NAME_PATTERN = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')
_TOP_KEY = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*\s*:')
_GAIT_KEY = re.compile(r'^  ([A-Za-z_][A-Za-z0-9_]*)\s*:')


def _scalar(value) -> str:
    """One YAML value on one line (mappings and lists in flow style)."""
    text = yaml.safe_dump(value, default_flow_style=True, sort_keys=False, width=10_000)
    text = text.strip()
    return text[:-4].strip() if text.endswith('\n...') or text.endswith(' ...') else text


def gait_block(name: str, spec: Mapping, comments: Sequence[str] = ()) -> list[str]:
    """The lines of one ``gaits:`` entry (two-space indent, keys in the spec's order)."""
    lines = [f'  {name}:\n']
    lines += [f'    # {c}\n' if c else '    #\n' for c in comments]
    for key, value in spec.items():
        lines.append(f'    {key}: {_scalar(value)}\n')
    return lines


def _splice(text: str, name: str, block: list[str]) -> str:
    lines = text.splitlines(keepends=True)
    try:
        top = next(i for i, line in enumerate(lines) if re.match(r'^gaits\s*:\s*(#.*)?$', line))
    except StopIteration:
        raise ValueError("the scene file has no top-level 'gaits:' section") from None
    end = next((i for i in range(top + 1, len(lines)) if _TOP_KEY.match(lines[i])), len(lines))
    start = None
    for i in range(top + 1, end):
        m = _GAIT_KEY.match(lines[i])
        if m and m.group(1) == name:
            start = i
            break
    if start is None:                 # a new gait: at the end of the section
        insert = end
        while insert > top + 1 and not lines[insert - 1].strip():
            insert -= 1
        if insert > 0 and not lines[insert - 1].endswith('\n'):
            lines[insert - 1] += '\n'
        return ''.join(lines[:insert] + block + lines[insert:])
    stop = next((i for i in range(start + 1, end) if _GAIT_KEY.match(lines[i])), end)
    # Comment lines just above the next gait belong to it, not to the replaced one.
    while stop > start + 1 and lines[stop - 1].startswith('  #'):
        stop -= 1
    return ''.join(lines[:start] + block + lines[stop:])


def write_scene_gait(scene_file: str | os.PathLike, name: str, spec: Mapping, *,
                     output: str | os.PathLike | None = None,
                     comments: Sequence[str] = ()) -> Path:
    """Put gait `spec` named `name` into scene file `scene_file` (or a copy, `output`).

    Raises
    ------
    ValueError
        A bad name, a file without a ``gaits:`` section.
    softsnap_model.scene.SceneError, softsnap_gaits.gaits.GaitError
        The resulting scene or gait is invalid (for example a gait faster than the
        winches); nothing is written then.
    """
    from softsnap_model.scene import load_scene
    from .gaits import make_gait
    if not isinstance(name, str) or not GAIT_NAME_PATTERN.match(name):
        raise ValueError(f'gait name must be a plain identifier, got {name!r}')
    source = Path(scene_file)
    target = Path(output) if output is not None else source
    text = _splice(source.read_text(), name, gait_block(name, dict(spec), comments))
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.scene-', suffix='.yaml', dir=target.parent)
    try:
        with os.fdopen(fd, 'w') as f:
            f.write(text)
        make_gait(name, load_scene(tmp))      # refuses anything the scene would refuse
        os.chmod(tmp, source.stat().st_mode & 0o777)
        os.replace(tmp, target)
    except BaseException:
        os.unlink(tmp)
        raise
    return target
