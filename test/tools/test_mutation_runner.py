"""scripts/mutation.py: its operators, its seeded spread sample, and a real run on a toy
package (mutants killed and survived as the toy's tests predict; the source untouched)."""
from __future__ import annotations

import hashlib
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / 'scripts'))
import mutation  # noqa: E402

TOY = '''\
"""Toy module."""
LIMIT = 10


def clamp(x):
    if x < 0:
        return 0
    if x > LIMIT and True:
        raise ValueError('too big')
    return x * 1
'''

TOY_TEST = '''\
import pytest
from toypkg.calc import clamp


def test_clamp():
    assert clamp(-3) == 0 and clamp(4) == 4
    with pytest.raises(ValueError):
        clamp(11)
'''


def make_toy(tmp_path: Path) -> tuple[Path, Path]:
    # The package where no test puts it on sys.path: only the overlay makes it importable.
    package = tmp_path / 'src' / 'toypkg'
    package.mkdir(parents=True)
    (package / '__init__.py').write_text('')
    (package / 'calc.py').write_text(TOY)
    (tmp_path / 'tests').mkdir()
    test = tmp_path / 'tests' / 'test_toy.py'
    test.write_text(TOY_TEST)
    return package / 'calc.py', test


def test_every_operator_is_found_once_and_compiles(tmp_path):
    source, _ = make_toy(tmp_path)
    descriptions = [m.description for m in mutation.collect_mutants(source)]
    expected = {
        'constant `10` -> `11`',
        "if condition `x < 0` forced True", "if condition `x < 0` forced False",
        '`<` -> `<=` in `x < 0`', '`<` -> `>=` in `x < 0`', 'constant `0` -> `1`',
        '`return 0` -> `return None`', '`>` -> `>=` in `x > LIMIT`', '`>` -> `<=` in `x > LIMIT`',
        '`and` -> `or` in `x > LIMIT and True`', 'constant `True` -> `False`',
        "`raise ValueError('too big')` removed", '`return x * 1` -> `return None`',
        '`*` -> `/` in `x * 1`', 'constant `1` -> `2`',
    }
    assert expected <= set(descriptions), expected - set(descriptions)
    assert not any('docstring' in d or 'Toy module' in d for d in descriptions)
    for m in mutation.collect_mutants(source):
        compile(m.apply(source.read_bytes()), 'mutant', 'exec')
        assert m.apply(source.read_bytes()) != source.read_bytes()


def test_spread_sample_is_seeded_and_covers_the_whole_file():
    items = list(range(1000))
    one = mutation.spread_sample(items, 100, seed=5)
    assert one == mutation.spread_sample(items, 100, seed=5)
    assert one != mutation.spread_sample(items, 100, seed=6)
    assert [x // 10 for x in one] == list(range(100))          # one from every tenth
    assert mutation.spread_sample(items[:50], 100, seed=5) == items[:50]


def test_equivalent_list_is_read_with_reasons(tmp_path):
    listing = tmp_path / 'eq.txt'
    listing.write_text('# comment\n\na.py::f::`>` -> `>=` in `x > 0`  # x is never 0\n')
    assert mutation.load_equivalent(listing) == {'a.py::f::`>` -> `>=` in `x > 0`': 'x is never 0'}


def test_a_run_kills_what_the_tests_see_and_reports_the_rest(tmp_path):
    source, test = make_toy(tmp_path)
    before = hashlib.sha256(source.read_bytes()).hexdigest()
    survivors = tmp_path / 'survivors.txt'
    out = subprocess.run(
        [sys.executable, str(REPO / 'scripts' / 'mutation.py'), '--files', str(source),
         '--tests', str(test), '--mutants', '0', '--workers', '1', '--timeout', '120',
         '--survivors-out', str(survivors), f'--pytest-args=--rootdir={tmp_path}'],
        capture_output=True, text=True, timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stdout + out.stderr
    assert hashlib.sha256(source.read_bytes()).hexdigest() == before
    # Untested by the toy test: the boundaries x == 0 and x == LIMIT (also `x < 1`), and
    # `* 1` -> `/ 1` (the same value here); everything else is killed.
    left = sorted(k.split('::')[-1] for k in survivors.read_text().splitlines())
    assert left == sorted(['`<` -> `<=` in `x < 0`', 'constant `0` -> `1`',
                           '`>` -> `>=` in `x > LIMIT`', '`*` -> `/` in `x * 1`'])
    assert '| 18 | 14 | 0 | 0 | 4 | 77.8 % |' in out.stdout.replace(str(source), 'toy')
    assert f'{source}:6: `<` -> `<=` in `x < 0`' in out.stdout
