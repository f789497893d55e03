#!/usr/bin/env python3
"""Seeded mutation testing: how many small bugs in a file would its tests miss?

Usage (from the repository root; `make mutation FILES=... TESTS=...` calls this):

    nice .venv/bin/python scripts/mutation.py \
        --files src/softsnap_driver/softsnap_driver/core.py \
        --tests test/softsnap_driver/test_core.py --mutants 120 --seed 38

Each file is parsed with `ast`; every place an operator below applies is a candidate
mutant. With more candidates than `--mutants`, the candidates (in source order) are cut
into `--mutants` equal runs and one is drawn from each with the seed, so the sample is
spread over the whole file and the same seed gives the same mutants on the same source.

Operators: comparisons flipped (`<` to `<=` and to `>=`, `==`/`!=`, `in`/`not in`,
`is`/`is not`), `and`/`or` swapped, arithmetic swapped (`+ -`, `* /`, `//` and `%`,
`**`, bit operators), unary `not`/`-` removed, constants changed (int n to n + 1, float x
to x + 1 or to 0.0 below 1, True/False swapped), `return value` to `return None`,
`raise` to `pass`, `if`/`elif`/`while`/ternary/comprehension conditions forced true or
false (`while` only forced false).

The source is never edited: each worker copies the file's top-level package into a
temporary overlay directory that comes first on PYTHONPATH (also in processes the tests
start), writes one mutant there at a time and runs the test files with pytest in a
subprocess with a timeout (its process group is killed on timeout or Ctrl-C). A mutant is
killed when pytest fails (or times out); it survives when every test passes. The run
checks first that the tests pass on the unmutated overlay and that the overlay is what
gets imported, and at the end that the source files are unchanged.

Equivalent mutants (no test can tell them apart from the original) are listed, each with
its reason, in scripts/mutation_equivalent.txt; they are reported apart and left out of the
score's denominator. Mark a line `# pragma: no mutate` to skip it (for logging only).
"""
from __future__ import annotations

import argparse
import ast
import concurrent.futures
import copy
import dataclasses
import hashlib
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
EQUIVALENT_FILE = REPO / 'scripts' / 'mutation_equivalent.txt'
MAX_WORKERS = 2  # the shared machine has two cores

COMPARE_FLIPS = {
    ast.Lt: (ast.LtE, ast.GtE), ast.LtE: (ast.Lt, ast.Gt),
    ast.Gt: (ast.GtE, ast.LtE), ast.GtE: (ast.Gt, ast.Lt),
    ast.Eq: (ast.NotEq,), ast.NotEq: (ast.Eq,),
    ast.In: (ast.NotIn,), ast.NotIn: (ast.In,),
    ast.Is: (ast.IsNot,), ast.IsNot: (ast.Is,),
}
BINOP_SWAPS = {
    ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult,
    ast.FloorDiv: ast.Div, ast.Mod: ast.FloorDiv, ast.Pow: ast.Mult,
    ast.BitAnd: ast.BitOr, ast.BitOr: ast.BitAnd, ast.BitXor: ast.BitOr,
    ast.LShift: ast.RShift, ast.RShift: ast.LShift, ast.MatMult: ast.Mult,
}
OP_TEXT = {
    ast.Lt: '<', ast.LtE: '<=', ast.Gt: '>', ast.GtE: '>=', ast.Eq: '==', ast.NotEq: '!=',
    ast.In: 'in', ast.NotIn: 'not in', ast.Is: 'is', ast.IsNot: 'is not',
    ast.Add: '+', ast.Sub: '-', ast.Mult: '*', ast.Div: '/', ast.FloorDiv: '//',
    ast.Mod: '%', ast.Pow: '**', ast.BitAnd: '&', ast.BitOr: '|', ast.BitXor: '^',
    ast.LShift: '<<', ast.RShift: '>>', ast.MatMult: '@', ast.And: 'and', ast.Or: 'or',
}


@dataclasses.dataclass(frozen=True)
class Mutant:
    """One small change of one file: bytes [start, end) of the source replaced."""
    path: str          # relative to the repository root
    line: int          # 1-based line of the changed code in the original source
    scope: str         # enclosing function or class (qualified), '<module>' at top level
    description: str   # what changed, e.g. "`<` -> `<=` in `count < low`"
    start: int
    end: int
    replacement: str

    @property
    def key(self) -> str:
        """Stable across edits elsewhere in the file (no line number)."""
        return f'{self.path}::{self.scope}::{self.description}'

    def apply(self, source: bytes) -> bytes:
        return source[:self.start] + self.replacement.encode() + source[self.end:]


def _short(text: str, limit: int = 70) -> str:
    text = ' '.join(text.split())
    return text if len(text) <= limit else text[:limit - 3] + '...'


class _Collector(ast.NodeVisitor):
    """Walks a module and records every candidate mutant in source order."""

    def __init__(self, path: str, source: bytes):
        self.path = path
        self.source = source
        self.text = source.decode()
        starts, offset = [], 0
        for line in source.splitlines(keepends=True):
            starts.append(offset)
            offset += len(line)
        starts.append(offset)
        self.line_starts = starts
        self.skip_lines = {i + 1 for i, line in enumerate(self.text.splitlines())
                           if 'pragma: no mutate' in line}
        self.scope: list[str] = []
        self.mutants: list[Mutant] = []

    # -- helpers --------------------------------------------------------------------
    def _span(self, node: ast.AST) -> tuple[int, int]:
        return (self.line_starts[node.lineno - 1] + node.col_offset,
                self.line_starts[node.end_lineno - 1] + node.end_col_offset)

    def _segment(self, node: ast.AST) -> str:
        start, end = self._span(node)
        return self.source[start:end].decode()

    def _add(self, node: ast.AST, description: str, replacement: str) -> None:
        if node.lineno in self.skip_lines:
            return
        start, end = self._span(node)
        self.mutants.append(Mutant(self.path, node.lineno, '.'.join(self.scope) or '<module>',
                                   description, start, end, replacement))

    def _replace_expr(self, node: ast.expr, new: ast.expr, what: str) -> None:
        self._add(node, f'{what} in `{_short(self._segment(node))}`',
                  '(' + ast.unparse(ast.fix_missing_locations(new)) + ')')

    def _force(self, test: ast.expr, kind: str, values=(True, False)) -> None:
        for value in values:
            self._add(test, f'{kind} condition `{_short(self._segment(test))}` forced {value}',
                      f'({value})')

    # -- scopes and things never mutated --------------------------------------------
    def _visit_scope(self, node) -> None:
        self.scope.append(node.name)
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            body = body[1:]  # docstring
        for decorator in getattr(node, 'decorator_list', []):
            self.visit(decorator)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for default in node.args.defaults + [d for d in node.args.kw_defaults if d]:
                self.visit(default)
        for statement in body:
            self.visit(statement)
        self.scope.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = visit_ClassDef = _visit_scope

    def visit_Module(self, node: ast.Module) -> None:
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            body = body[1:]
        for statement in body:
            if (isinstance(statement, ast.If) and isinstance(statement.test, ast.Compare)
                    and ast.unparse(statement.test.left) == '__name__'):
                continue  # script entry point
            self.visit(statement)

    def visit_AnnAssign(self, node: ast.AnnAssign) -> None:
        if node.value is not None:
            self.visit(node.value)  # not the annotation

    def visit_JoinedStr(self, node: ast.JoinedStr) -> None:
        pass  # f-string positions are unreliable before 3.12; messages only

    def visit_Assert(self, node: ast.Assert) -> None:
        pass

    def visit_Assign(self, node: ast.Assign) -> None:
        if any(isinstance(t, ast.Name) and t.id == '__all__' for t in node.targets):
            return
        self.generic_visit(node)

    def visit_Import(self, node) -> None:
        pass

    visit_ImportFrom = visit_Import

    # -- operators ------------------------------------------------------------------
    def visit_Compare(self, node: ast.Compare) -> None:
        for index, op in enumerate(node.ops):
            for flipped in COMPARE_FLIPS.get(type(op), ()):
                new = copy.deepcopy(node)
                new.ops[index] = flipped()
                self._replace_expr(node, new, f'`{OP_TEXT[type(op)]}` -> `{OP_TEXT[flipped]}`')
        self.generic_visit(node)

    def visit_BoolOp(self, node: ast.BoolOp) -> None:
        new = copy.deepcopy(node)
        new.op = ast.Or() if isinstance(node.op, ast.And) else ast.And()
        self._replace_expr(node, new, f'`{OP_TEXT[type(node.op)]}` -> `{OP_TEXT[type(new.op)]}`')
        self.generic_visit(node)

    def visit_BinOp(self, node: ast.BinOp) -> None:
        swapped = BINOP_SWAPS.get(type(node.op))
        if swapped is not None and not (isinstance(node.op, ast.Mod)
                                        and isinstance(node.left, ast.Constant)
                                        and isinstance(node.left.value, str)):
            new = copy.deepcopy(node)
            new.op = swapped()
            self._replace_expr(node, new, f'`{OP_TEXT[type(node.op)]}` -> `{OP_TEXT[swapped]}`')
        self.generic_visit(node)

    def visit_AugAssign(self, node: ast.AugAssign) -> None:
        swapped = BINOP_SWAPS.get(type(node.op))
        if swapped is not None:
            new = copy.deepcopy(node)
            new.op = swapped()
            self._add(node, f'`{OP_TEXT[type(node.op)]}=` -> `{OP_TEXT[swapped]}=` in '
                      f'`{_short(self._segment(node))}`', ast.unparse(new))
        self.visit(node.value)

    def visit_UnaryOp(self, node: ast.UnaryOp) -> None:
        if isinstance(node.op, (ast.Not, ast.USub, ast.Invert)) and not (
                isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant)):
            self._replace_expr(node, node.operand, 'unary operator removed')
        elif isinstance(node.op, ast.USub):  # a negative literal: change the number
            value = node.operand.value
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                self._constant(node, -value)
            return
        self.generic_visit(node)

    def _constant(self, node: ast.expr, value) -> None:
        if isinstance(value, bool):
            new = not value
        elif isinstance(value, int):
            new = value + 1
        elif isinstance(value, float):
            new = 1.0 if value == 0 else (value + 1.0 if abs(value) >= 1 else 0.0)
        else:
            return
        self._add(node, f'constant `{self._segment(node)}` -> `{new!r}`', f'({new!r})')

    def visit_Constant(self, node: ast.Constant) -> None:
        self._constant(node, node.value)

    def visit_Return(self, node: ast.Return) -> None:
        if node.value is not None and not (isinstance(node.value, ast.Constant)
                                           and node.value.value is None):
            self._add(node, f'`{_short(self._segment(node))}` -> `return None`', 'return None')
            self.visit(node.value)

    def visit_Raise(self, node: ast.Raise) -> None:
        self._add(node, f'`{_short(self._segment(node))}` removed', 'pass')

    def visit_If(self, node: ast.If) -> None:
        self._force(node.test, 'if')
        self.generic_visit(node)

    def visit_While(self, node: ast.While) -> None:
        self._force(node.test, 'while', values=(False,))  # forced true would only hang
        self.generic_visit(node)

    def visit_IfExp(self, node: ast.IfExp) -> None:
        self._force(node.test, 'ternary')
        self.generic_visit(node)

    def visit_comprehension(self, node: ast.comprehension) -> None:
        for test in node.ifs:
            self._force(test, 'filter')
        self.generic_visit(node)

    def visit_Subscript(self, node: ast.Subscript) -> None:
        self.visit(node.value)
        if not (isinstance(node.value, ast.Name) and node.value.id in {
                'list', 'dict', 'tuple', 'set', 'type', 'Optional', 'Callable'}):
            self.visit(node.slice)  # not type parameters such as tuple[int, int]


def display_path(path: Path) -> str:
    """``path`` relative to the repository root when inside it, else absolute."""
    path = path.resolve()
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def collect_mutants(path: Path) -> list[Mutant]:
    """Every candidate mutant of one file that still compiles, in source order."""
    source = path.read_bytes()
    relative = display_path(path)
    collector = _Collector(relative, source)
    collector.visit(ast.parse(source, filename=relative))
    seen, mutants, occurrences = set(), [], {}
    for mutant in sorted(collector.mutants, key=lambda m: (m.start, m.end, m.description)):
        # The same change twice in one scope (two `0` constants): number the later ones
        # so that every key names one mutant.
        nth = occurrences[mutant.scope, mutant.description] = \
            occurrences.get((mutant.scope, mutant.description), 0) + 1
        if nth > 1:
            mutant = dataclasses.replace(mutant, description=f'{mutant.description} ({nth})')
        mutated = mutant.apply(source)
        digest = hashlib.sha1(mutated).digest()
        if digest in seen or mutated == source:
            continue
        try:
            compile(mutated, relative, 'exec')
        except SyntaxError:
            continue
        seen.add(digest)
        mutants.append(mutant)
    return mutants


def spread_sample(mutants: list[Mutant], count: int, seed: int) -> list[Mutant]:
    """``count`` mutants, one drawn at random (seeded) from each of ``count`` equal runs."""
    if count <= 0 or count >= len(mutants):
        return list(mutants)
    rng = random.Random(seed)
    picked = []
    for index in range(count):
        low = index * len(mutants) // count
        high = (index + 1) * len(mutants) // count
        picked.append(mutants[rng.randrange(low, high)])
    return picked


def load_equivalent(path: Path = EQUIVALENT_FILE) -> dict[str, str]:
    """``key -> reason`` from lines ``<key>  # <reason>`` (blank lines and ``#`` lines skipped)."""
    equivalent = {}
    if path.exists():
        for line in path.read_text().splitlines():
            if not line.strip() or line.lstrip().startswith('#'):
                continue
            key, _, reason = line.partition('  # ')
            equivalent[key.strip()] = reason.strip()
    return equivalent


def package_root(path: Path) -> Path:
    """The top-level package directory that holds ``path`` (highest dir with __init__.py)."""
    root = path.parent
    while (root.parent / '__init__.py').exists():
        root = root.parent
    if not (root / '__init__.py').exists():
        raise SystemExit(f'{path} is not inside a Python package')
    return root


def module_name(path: Path) -> str:
    root = package_root(path)
    parts = path.relative_to(root.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


@dataclasses.dataclass
class Outcome:
    mutant: Mutant
    status: str        # killed, survived, timeout
    seconds: float


class Runner:
    """Workers with their own overlay directory; runs pytest on one mutant at a time."""

    def __init__(self, targets: list[Path], tests: list[str], timeout_s: float,
                 workers: int, pytest_args: list[str]):
        self.targets = targets
        self.tests = tests
        self.timeout_s = timeout_s
        self.pytest_args = pytest_args
        self.tempdir = tempfile.TemporaryDirectory(prefix='softsnap-mutation-')
        self.overlays = []
        roots = sorted({package_root(t) for t in targets})
        for index in range(workers):
            overlay = Path(self.tempdir.name) / f'worker{index}'
            for root in roots:
                shutil.copytree(root, overlay / root.name,
                                ignore=shutil.ignore_patterns('__pycache__'))
            self.overlays.append(overlay)
        self.free = list(self.overlays)
        self.lock = threading.Lock()
        self.processes: set[subprocess.Popen] = set()
        self.stopping = False

    def env(self, overlay: Path) -> dict[str, str]:
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(overlay),
                                                          env.get('PYTHONPATH', '')]))
        env['PYTHONDONTWRITEBYTECODE'] = '1'  # pyc mtimes have 1 s resolution: never stale
        return env

    def overlay_file(self, overlay: Path, target: Path) -> Path:
        return overlay / target.resolve().relative_to(package_root(target).parent)

    def check_overlay_imported(self) -> None:
        for target in self.targets:
            name = module_name(target)
            out = subprocess.run(
                [sys.executable, '-c', f'import {name} as m; print(m.__file__)'],
                env=self.env(self.overlays[0]), capture_output=True, text=True, cwd=REPO)
            imported = Path(out.stdout.strip() or '?').resolve()
            expected = self.overlay_file(self.overlays[0], target).resolve()
            if imported != expected:
                raise SystemExit(f'overlay not imported for {name}: got {imported} '
                                 f'({out.stderr.strip()[-300:]})')

    def run_tests(self, overlay: Path, timeout_s: float | None) -> tuple[str, float, str]:
        command = [sys.executable, '-m', 'pytest', '-x', '-q', '-p', 'no:cacheprovider',
                   *self.pytest_args, *self.tests]
        start = time.monotonic()
        process = subprocess.Popen(command, cwd=REPO, env=self.env(overlay),
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   start_new_session=True)
        with self.lock:
            self.processes.add(process)
        try:
            output, _ = process.communicate(timeout=timeout_s)
            status = 'survived' if process.returncode == 0 else 'killed'
            if process.returncode in (4, 5):  # usage error, no tests: not a verdict
                status = 'error'
            if self.stopping:                 # killed by Ctrl-C, not by a test
                status = 'skipped'
        except subprocess.TimeoutExpired:
            self.kill(process)
            output, _ = process.communicate()
            status = 'skipped' if self.stopping else 'timeout'
        finally:
            with self.lock:
                self.processes.discard(process)
        return status, time.monotonic() - start, output.decode(errors='replace')

    @staticmethod
    def kill(process: subprocess.Popen) -> None:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass

    def run_mutant(self, mutant: Mutant) -> Outcome:
        if self.stopping:
            return Outcome(mutant, 'skipped', 0.0)
        with self.lock:
            overlay = self.free.pop()
        target = self.overlay_file(overlay, REPO / mutant.path)
        original = (REPO / mutant.path).read_bytes()
        try:
            target.write_bytes(mutant.apply(original))
            status, seconds, output = self.run_tests(overlay, self.timeout_s)
            if status == 'error' and not self.stopping:
                raise RuntimeError(f'pytest could not run for {mutant.key}:\n{output[-2000:]}')
            return Outcome(mutant, status, seconds)
        finally:
            target.write_bytes(original)
            with self.lock:
                self.free.append(overlay)

    def kill_running(self) -> None:
        with self.lock:
            for process in list(self.processes):
                self.kill(process)

    def close(self) -> None:
        self.stopping = True
        self.kill_running()
        self.tempdir.cleanup()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--files', nargs='+', required=True,
                        help='source files to mutate (space-separated list accepted)')
    parser.add_argument('--tests', nargs='+', required=True, help='pytest paths or node ids')
    parser.add_argument('--mutants', type=int, default=120,
                        help='mutants per file, spread over it (0: all candidates)')
    parser.add_argument('--seed', type=int, default=38)
    parser.add_argument('--workers', type=int, default=1, help=f'at most {MAX_WORKERS}')
    parser.add_argument('--timeout', type=float, default=0.0,
                        help='seconds per mutant (default: 5 x the clean run + 30 s)')
    parser.add_argument('--lines', default='', help='only mutants on these lines, e.g. 80-120')
    parser.add_argument('--list', action='store_true', help='list the mutants, run nothing')
    parser.add_argument('--pytest-args', default='', help='extra pytest arguments')
    parser.add_argument('--survivors-out', default='',
                        help='write the keys of the surviving mutants to this file')
    parser.add_argument('--only', default='',
                        help='run only the sampled mutants whose keys this file lists (a '
                             '--survivors-out file: re-check survivors after adding tests)')
    args = parser.parse_args(argv)
    files = [Path(f).resolve() for spec in args.files for f in spec.split()]
    tests = [t for spec in args.tests for t in spec.split()]
    workers = max(1, min(args.workers, MAX_WORKERS))
    equivalent = load_equivalent()

    sampled: list[Mutant] = []
    for path in files:
        candidates = collect_mutants(path)
        picked = spread_sample(candidates, args.mutants, args.seed)
        if args.lines:
            low, _, high = args.lines.partition('-')
            picked = [m for m in picked if int(low) <= m.line <= int(high or low)]
        if args.only:
            wanted = set(Path(args.only).read_text().splitlines())
            picked = [m for m in picked if m.key in wanted]
        print(f'{display_path(path)}: {len(candidates)} candidate mutants, {len(picked)} sampled '
              f'(seed {args.seed})')
        sampled += picked
    if args.list:
        for m in sampled:
            mark = '  [equivalent]' if m.key in equivalent else ''
            print(f'  {m.path}:{m.line}: {m.description}{mark}')
        return 0

    digests = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}
    runner = Runner(files, tests, args.timeout, workers, args.pytest_args.split())
    outcomes: list[Outcome] = []
    try:
        runner.check_overlay_imported()
        status, clean_s, output = runner.run_tests(runner.overlays[0], None)
        if status != 'survived':
            print(output[-4000:])
            print('the tests fail on the unmutated source: fix them first')
            return 2
        if not args.timeout:
            runner.timeout_s = 5 * clean_s + 30
        print(f'clean run {clean_s:.1f} s; timeout {runner.timeout_s:.0f} s per mutant; '
              f'{workers} worker(s); {len(sampled)} mutants', flush=True)
        pool = concurrent.futures.ThreadPoolExecutor(workers)
        try:
            for index, outcome in enumerate(pool.map(runner.run_mutant, sampled), 1):
                outcomes.append(outcome)
                if outcome.status == 'survived':
                    m = outcome.mutant
                    tag = ' (listed equivalent)' if m.key in equivalent else ''
                    print(f'  [{index}/{len(sampled)}] SURVIVED {m.path}:{m.line}: '
                          f'{m.description}{tag}', flush=True)
                elif index % 10 == 0:
                    print(f'  [{index}/{len(sampled)}] ...', flush=True)
        finally:
            # On Ctrl-C: no new mutant starts, the running pytest groups are killed (their
            # outcomes are not counted), queued ones are dropped.
            runner.stopping = True
            runner.kill_running()
            pool.shutdown(wait=True, cancel_futures=True)
    except KeyboardInterrupt:
        print(f'\ninterrupted: partial results below ({len(outcomes)} of {len(sampled)} '
              f'mutants)', flush=True)
    finally:
        runner.close()
        for path, digest in digests.items():
            if hashlib.sha256(path.read_bytes()).hexdigest() != digest:
                print(f'WARNING: {path} changed during the run (edited by someone else?)')
    return report(files, outcomes, equivalent, args)


def report(files: list[Path], outcomes: list[Outcome], equivalent: dict[str, str],
           args) -> int:
    print(f'\nmutation score (seed {args.seed}, {args.mutants or "all"} mutants per file)')
    print('| file | mutants | killed | timeouts | equivalent | survived | score |')
    print('| --- | --- | --- | --- | --- | --- | --- |')
    for path in files:
        relative = display_path(path)
        mine = [o for o in outcomes if o.mutant.path == relative and o.status != 'skipped']
        killed = sum(o.status in ('killed', 'timeout') for o in mine)
        timeouts = sum(o.status == 'timeout' for o in mine)
        equal = sum(o.status == 'survived' and o.mutant.key in equivalent for o in mine)
        survived = sum(o.status == 'survived' and o.mutant.key not in equivalent for o in mine)
        counted = killed + survived
        score = f'{100 * killed / counted:.1f} %' if counted else '-'
        print(f'| `{relative}` | {len(mine)} | {killed} | {timeouts} | {equal} | {survived} '
              f'| {score} |')
    survivors = [o.mutant for o in outcomes if o.status == 'survived']
    if args.survivors_out:
        Path(args.survivors_out).write_text(''.join(f'{m.key}\n' for m in survivors
                                                    if m.key not in equivalent))
    if survivors:
        print('\nsurvivors:')
        for m in sorted(survivors, key=lambda m: (m.path, m.line)):
            reason = equivalent.get(m.key)
            note = f'  [equivalent: {reason}]' if reason else ''
            print(f'  {m.path}:{m.line}: {m.description}{note}')
            if not reason:
                print(f'      key: {m.key}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
