"""scripts/bootstrap.sh on Python 3.11 and 3.12: the wheel CMake path rewrite for any
builder interpreter, and one clear line for an unsupported Python.

A full 3.12 bootstrap of a fresh clone was run by hand (docs/install.md gives the command
and its result); here the two parts that differ between versions are run for both.
"""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
FIX = REPO / 'scripts' / 'fix_wheel_cmake_paths.sh'

# The shape of the line the message wheels export (builtin_interfaces' Python generator
# target), with the manylinux builder's interpreter of each version.
EXPORT = '''set_target_properties(builtin_interfaces::builtin_interfaces__rosidl_generator_py PROPERTIES
  INTERFACE_INCLUDE_DIRECTORIES "/opt/python/{tag}-{tag}/lib/python{ver}/site-packages/numpy/_core/include;/opt/python/{tag}-{tag}/include/python{ver};${{_IMPORT_PREFIX}}/include/builtin_interfaces"
  INTERFACE_LINK_LIBRARIES "builtin_interfaces::builtin_interfaces__rosidl_generator_c"
)
'''


@pytest.mark.parametrize('ver', ['3.11', '3.12'])
def test_the_rewrite_points_any_builder_python_at_this_machines(tmp_path, ver):
    tag = 'cp' + ver.replace('.', '')
    export = tmp_path / 'builtin_interfaces__rosidl_generator_pyExport.cmake'
    export.write_text(EXPORT.format(tag=tag, ver=ver))
    untouched = tmp_path / 'other.cmake'
    untouched.write_text('set(X "/usr/include")\n')
    py_inc, np_inc = f'/venv/include/python{ver}', f'/venv/lib/python{ver}/numpy/_core/include'

    subprocess.run(['bash', str(FIX), py_inc, np_inc, str(export), str(untouched)], check=True)

    text = export.read_text()
    assert '/opt/python' not in text
    assert f'"{np_inc};{py_inc};${{_IMPORT_PREFIX}}/include/builtin_interfaces"' in text
    assert untouched.read_text() == 'set(X "/usr/include")\n'
    # Idempotent: a second run (every bootstrap runs it) changes nothing.
    subprocess.run(['bash', str(FIX), py_inc, np_inc, str(export)], check=True)
    assert export.read_text() == text


def test_the_real_wheels_exports_name_no_builder_path_after_the_bootstrap():
    """The venv this test runs in was bootstrapped: no exported target names /opt/python."""
    import sys
    exports = list((Path(sys.prefix) / 'share').glob('*/cmake/*__rosidl_generator_pyExport.cmake'))
    assert len(exports) > 5
    assert not [p for p in exports if '/opt/python/' in p.read_text()]


def _bootstrap_copy(tmp_path: Path) -> Path:
    root = tmp_path / 'clone'
    (root / 'scripts').mkdir(parents=True)
    shutil.copy(REPO / 'scripts' / 'bootstrap.sh', root / 'scripts')
    shutil.copy(FIX, root / 'scripts')
    shutil.copytree(REPO / 'requirements', root / 'requirements')
    return root


@pytest.mark.parametrize('python', ['no-such-python3', 'python3.10'])
def test_an_unsupported_python_is_refused_in_one_line_before_anything_is_installed(tmp_path, python):
    if python == 'python3.10':
        candidates = [shutil.which('python3.10'),
                      *sorted(Path('/root/.pyenv/versions').glob('3.10*/bin/python3.10'))]
        runnable = [str(c) for c in candidates if c and subprocess.run(
            [str(c), '-V'], capture_output=True).returncode == 0]
        if not runnable:
            pytest.skip('no runnable Python 3.10 here (the missing interpreter case still runs)')
        python = runnable[0]
    root = _bootstrap_copy(tmp_path)
    done = subprocess.run(['bash', str(root / 'scripts' / 'bootstrap.sh')], capture_output=True,
                          text=True, timeout=60, env={'PATH': '/usr/bin:/bin', 'PYTHON': python})
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert 'unsupported Python' in lines[0] and '3.11 or 3.12' in lines[0]
    assert ('3.10' if 'python3.10' in python else 'not runnable') in lines[0]
    assert not (root / '.venv').exists()
