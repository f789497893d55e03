"""The shape of the code (docs/architecture.md): a one-way package stack, every import of
another of our packages declared, no source file over 800 lines, one home per piece of
plumbing.

Read from the source with ``ast`` (imports inside functions count too), so a new cycle
or an undeclared import fails here, not on a user's machine with a partial install.
"""
from __future__ import annotations

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / 'src'
#: Bottom first: a package may import only packages before it in this list, except the
#: ones on its own level (driver and vision stand side by side and ignore each other).
STACK = [('softsnap_interfaces',), ('softsnap_ros',), ('softsnap_model',),
         ('softsnap_driver', 'softsnap_vision'), ('softsnap_gaits',)]
LEVEL = {package: level for level, packages in enumerate(STACK) for package in packages}
MAX_LINES = 800


def _python_files(package: str):
    return sorted((SRC / package).rglob('*.py'))


def _imported_packages(path: Path) -> dict[str, int]:
    """Our packages ``path`` imports (at any depth of the module), each with a line."""
    found = {}
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            top = name.split('.')[0]
            if top in LEVEL:
                found.setdefault(top, node.lineno)
    return found


def _declared(package: str) -> set[str]:
    root = ET.parse(SRC / package / 'package.xml').getroot()
    return {e.text.strip() for tag in ('depend', 'exec_depend', 'build_depend')
            for e in root.iter(tag)}


def test_the_stack_lists_every_package_of_src():
    assert {p.name for p in SRC.iterdir() if (p / 'package.xml').exists()} == set(LEVEL)


@pytest.mark.parametrize('package', [p for p in LEVEL if p != 'softsnap_interfaces'])
def test_a_package_imports_only_packages_below_it_and_declares_them(package):
    declared = _declared(package)
    wrong, undeclared = [], []
    for path in _python_files(package):
        for other, line in _imported_packages(path).items():
            where = f'{path.relative_to(REPO)}:{line} imports {other}'
            if other != package and LEVEL[other] >= LEVEL[package]:
                wrong.append(where)
            if other != package and other not in declared:
                undeclared.append(where)
    assert not wrong, 'imports beside or above in the stack:\n' + '\n'.join(wrong)
    assert not undeclared, f'not declared in {package}/package.xml:\n' + '\n'.join(undeclared)


def test_no_source_file_is_over_800_lines():
    files = [*SRC.rglob('*.py'), *(REPO / 'benchmarks').glob('*.py'),
             *(REPO / 'scripts').glob('*.py')]
    long = {str(p.relative_to(REPO)): n for p in files
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f'files over {MAX_LINES} lines: {long}'


def _python_sources():
    for path in [*SRC.rglob('*.py'), *(REPO / 'benchmarks').glob('*.py'),
                 *(REPO / 'test').rglob('*.py')]:
        if path != Path(__file__).resolve():
            yield path, path.read_text()


@pytest.mark.parametrize('pattern, home', [
    (r'^\s*MM_PER_M\s*=', 'src/softsnap_ros/softsnap_ros/units.py'),
    (r'^\s*NS_PER_S\s*=', 'src/softsnap_ros/softsnap_ros/units.py'),
    (r'^\s*TIME_SEC_MAX\s*=', 'src/softsnap_ros/softsnap_ros/units.py'),
    # The private C binding of rclpy: only the one wait loop uses it.
    (r'implementation_singleton', 'src/softsnap_ros/softsnap_ros/wait_loop.py'),
    # One CDR codec: struct layouts of our messages live in softsnap_ros.cdr only.
    (r'^class \w*(Wire|Cdr)\b', 'src/softsnap_ros/softsnap_ros/cdr/'),
])
def test_one_home_for_each_piece_of_plumbing(pattern, home):
    regex = re.compile(pattern, re.MULTILINE)
    elsewhere = [str(path.relative_to(REPO)) for path, text in _python_sources()
                 if regex.search(text) and not str(path.relative_to(REPO)).startswith(home)]
    assert not elsewhere, f'{pattern!r} outside {home}: {elsewhere}'


def test_the_tests_import_no_benchmark_through_sys_path():
    offenders = [str(path.relative_to(REPO)) for path, text in _python_sources()
                 if 'test' in path.parts[len(REPO.parts):][:1]
                 and re.search(r"sys\.path\.(append|insert)\(.*benchmarks", text)]
    assert not offenders, offenders


#: Test folders that are not one package's: the whole graph end to end, the repo's tools.
CROSS_CUTTING_TESTS = {'e2e', 'tools'}


def test_the_tests_mirror_the_packages():
    """test/<package>/ per package of src (plus e2e/ and tools/), and a test in a
    package's folder exercises that package: imports it or starts one of its executables."""
    folders = {p.name for p in (REPO / 'test').iterdir()
               if p.is_dir() and p.name != '__pycache__'}
    assert folders - CROSS_CUTTING_TESTS <= set(LEVEL), folders - set(LEVEL)
    assert set(LEVEL) <= folders, set(LEVEL) - folders
    strays = []
    for package in LEVEL:
        setup = SRC / package / 'setup.py'
        executables = re.findall(r"'(\w+) = ", setup.read_text()) if setup.exists() else []
        for path in sorted((REPO / 'test' / package).glob('test_*.py')):
            text = path.read_text()
            if not re.search(rf'\b{package}\b', text) and not any(
                    re.search(rf"'{name}'", text) for name in executables):
                strays.append(str(path.relative_to(REPO)))
    assert not strays, f'tests that do not touch their folder\'s package: {strays}'


def test_the_test_folders_benchmarks_reach_exist():
    """A benchmark that borrows a test helper (the mpmath reference, the renderer) names
    its folder; a folder moved without its benchmarks fails here, not in a later run."""
    named = []
    for path in sorted((REPO / 'benchmarks').glob('*.py')):
        for folder in re.findall(r"'test' / '(\w+)'", path.read_text()):
            named.append((path.name, folder))
    assert named, 'no benchmark names a test folder: the pattern is stale'
    missing = [(name, folder) for name, folder in named
               if not (REPO / 'test' / folder).is_dir()]
    assert not missing, missing
