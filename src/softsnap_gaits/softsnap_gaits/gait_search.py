"""CMA-ES over a gait family, rollouts in parallel on processes or on Ray.

No ROS. :func:`search` asks ``cma`` for a population of cube points, decodes each with
the family (:mod:`softsnap_gaits.gait_family`), scores every (candidate, setting) pair as
one task (:func:`evaluate_task`, a pure function of its arguments) on a backend, and tells
CMA-ES the negated aggregate scores. Results are put back in task order whatever order the
workers finish in, and each task depends only on its own arguments (the jitter's stream
is seeded by the setting, the physics is deterministic), so a seed gives the same search
on every backend and worker count.

Backends (:func:`make_backend`):

* ``serial``: in this process (what ``--workers 1`` uses);
* ``process``: :class:`concurrent.futures.ProcessPoolExecutor` with ``workers`` spawned
  processes;
* ``ray``: Ray tasks on an existing cluster (``address``) or a local one; ``ray`` is
  imported only here.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .gait_family import GaitFamily
from .gait_objective import (DEFAULT_SETTINGS, Penalties, SimSetting, aggregate, rollout,
                             score, with_seed)

__all__ = ['SearchConfig', 'Generation', 'SearchResult', 'search', 'evaluate_task',
           'make_backend', 'SerialBackend', 'ProcessBackend', 'RayBackend']


@dataclass(frozen=True)
class SearchConfig:
    """What to search and how hard.

    Attributes
    ----------
    scene : str
        Scene name or path (every worker loads it).
    family : str
        ``pulse``/``walk`` or ``wave``/``concertina``.
    seed : int
        Seeds CMA-ES and the settings' jitter.
    generations, popsize : int
        Budget: ``generations * popsize`` candidates, each rolled out once per setting.
    sigma0 : float
        CMA-ES's initial step size in the unit cube.
    seconds : float
        Simulated gait time per rollout (s).
    heading_deg : float or None
        Direction of travel scored, degrees counter-clockwise from the robot's x axis;
        None: the straight-line distance in any direction.
    warmup_cycles : int
        Gait cycles run before the measured ones (see :func:`rollout`).
    aggregate : str
        ``mean`` or ``worst`` over the settings.
    settings : tuple of SimSetting
    x0 : sequence of float, optional
        Start point in the cube (default its centre).
    """

    scene: str
    family: str = 'pulse'
    seed: int = 1
    generations: int = 10
    popsize: int = 8
    sigma0: float = 0.25
    seconds: float = 6.0
    heading_deg: float | None = 0.0
    warmup_cycles: int = 0
    aggregate: str = 'mean'
    settings: tuple[SimSetting, ...] = DEFAULT_SETTINGS
    penalties: Penalties = Penalties()
    x0: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Generation:
    """One generation: its best candidate and the best so far."""

    index: int
    evaluations: int            # candidates scored so far
    rollouts: int               # rollouts run so far
    best_score: float           # best aggregate score in this generation (mm/s)
    best_so_far: float
    mean_score: float
    wall_s: float


@dataclass(frozen=True)
class SearchResult:
    """A finished search.

    Attributes
    ----------
    best_x, best_spec, best_score : the best candidate ever scored (cube point, gait spec,
        aggregate score mm/s) and ``best_scores`` its score per setting.
    history : list of Generation
    start_spec, start_score : the start point's spec and aggregate score (scored first).
    """

    best_x: np.ndarray
    best_spec: dict
    best_score: float
    best_scores: tuple[float, ...]
    best_results: tuple
    start_spec: dict
    start_score: float
    history: list[Generation] = field(default_factory=list)
    rollouts: int = 0
    wall_s: float = 0.0


def evaluate_task(task: tuple) -> tuple:
    """(scene, spec, setting, seconds, heading, warmup cycles) -> the rollout's RolloutResult.

    Top-level and pure, so any worker of any backend computes the same answer.
    """
    scene, spec, setting, seconds, heading, warmup = task
    return rollout(scene, spec, setting, seconds=seconds, heading_deg=heading,
                   warmup_cycles=warmup)


class SerialBackend:
    """Tasks one after another in this process."""

    name = 'serial'
    workers = 1

    def map(self, tasks: Sequence) -> list:
        return [evaluate_task(t) for t in tasks]

    def close(self) -> None:
        pass


class ProcessBackend:
    """A pool of spawned processes (spawn: no MuJoCo or thread state is forked)."""

    name = 'process'

    def __init__(self, workers: int):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        self.workers = int(workers)
        self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                         mp_context=multiprocessing.get_context('spawn'))

    def map(self, tasks: Sequence) -> list:
        # map() returns in submission order, whoever finishes first.
        return list(self._pool.map(evaluate_task, tasks))

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


#: Tries to start a local Ray before giving up.
LOCAL_RAY_START_ATTEMPTS = 3


class RayBackend:
    """Ray tasks: on the cluster at `address`, or a local Ray (``ray.init`` with `init_kwargs`)."""

    name = 'ray'

    def __init__(self, address: str | None = None, **init_kwargs):
        import ray
        self._ray = ray
        self._owned = not ray.is_initialized()
        if self._owned:
            for attempt in range(LOCAL_RAY_START_ATTEMPTS):
                try:
                    ray.init(address=address, **init_kwargs)
                    break
                except Exception:
                    # Ray gives a starting node a fixed 30 s to register: a machine loaded
                    # many times over misses it (seen at a load average of 45 on 2 CPUs).
                    ray.shutdown()
                    if address is not None or attempt + 1 == LOCAL_RAY_START_ATTEMPTS:
                        raise
        self.workers = int(ray.cluster_resources().get('CPU', 1))
        self._remote = ray.remote(num_cpus=1)(evaluate_task)

    def map(self, tasks: Sequence) -> list:
        refs = [self._remote.remote(t) for t in tasks]
        return self._ray.get(refs)       # in submission order

    def close(self) -> None:
        if self._owned:
            self._ray.shutdown()


def make_backend(name: str = 'process', workers: int = 1, address: str | None = None,
                 **ray_init):
    """``serial``, ``process`` (``workers`` processes; 1 worker runs serially) or ``ray``."""
    if name == 'ray':
        return RayBackend(address, **ray_init)
    if name == 'serial' or (name == 'process' and int(workers) <= 1):
        return SerialBackend()
    if name == 'process':
        return ProcessBackend(workers)
    raise ValueError(f"backend must be 'process', 'serial' or 'ray', got {name!r}")


def _score_population(backend, config: SearchConfig, settings, decoded) -> list:
    tasks = [(config.scene, d.spec, s, config.seconds, config.heading_deg, config.warmup_cycles)
             for d in decoded for s in settings]
    results = backend.map(tasks)
    n = len(settings)
    out = []
    for i, d in enumerate(decoded):
        rows = results[i * n:(i + 1) * n]
        per = [score(r, d.speed_excess, config.penalties) for r in rows]
        out.append((aggregate(per, config.aggregate), tuple(per), tuple(rows)))
    return out


def search(config: SearchConfig, family: GaitFamily, backend,
           progress: Callable[[Generation], None] | None = None,
           on_best: Callable[[dict, float], None] | None = None) -> SearchResult:
    """Run CMA-ES (``cma``) on `family` with `backend`; see the module docstring.

    `progress(generation)` is called after every generation, `on_best(spec, score)` each
    time the best candidate improves (a checkpoint: a stopped search keeps its best).
    """
    import cma
    started = time.monotonic()
    settings = with_seed(config.settings, config.seed)
    x0 = np.full(family.dimension, 0.5) if config.x0 is None else np.asarray(config.x0, float)
    start = family.decode(x0)
    (start_score, start_per, start_rows), = _score_population(backend, config, settings, [start])
    best = (start_score, x0.copy(), start.spec, start_per, start_rows)
    rollouts = len(settings)
    es = cma.CMAEvolutionStrategy(
        list(x0), config.sigma0,
        {'seed': int(config.seed), 'popsize': int(config.popsize), 'bounds': [0.0, 1.0],
         'verbose': -9, 'maxiter': int(config.generations)})
    history = []
    for g in range(int(config.generations)):
        xs = es.ask()
        decoded = [family.decode(x) for x in xs]
        scored = _score_population(backend, config, settings, decoded)
        rollouts += len(decoded) * len(settings)
        values = [s[0] for s in scored]
        # cma minimises; a non-finite score (never expected) counts as very bad.
        es.tell(xs, [-v if math.isfinite(v) else 1e9 for v in values])
        k = int(np.argmax(values))
        if values[k] > best[0]:
            best = (values[k], np.asarray(xs[k]).copy(), decoded[k].spec, scored[k][1],
                    scored[k][2])
            if on_best is not None:
                on_best(best[2], float(best[0]))
        gen = Generation(index=g + 1, evaluations=(g + 1) * len(xs) + 1, rollouts=rollouts,
                         best_score=float(values[k]), best_so_far=float(best[0]),
                         mean_score=float(np.mean(values)), wall_s=time.monotonic() - started)
        history.append(gen)
        if progress is not None:
            progress(gen)
    return SearchResult(best_x=best[1], best_spec=best[2], best_score=float(best[0]),
                        best_scores=best[3], best_results=best[4], start_spec=start.spec,
                        start_score=float(start_score), history=history, rollouts=rollouts,
                        wall_s=time.monotonic() - started)
