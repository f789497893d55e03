"""What a threading design returns and how it stops: :class:`DesignResult`, the
tolerance report :class:`DesignSensitivity`, the stop exceptions and the progress monitor."""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np



@dataclasses.dataclass(frozen=True)
class DesignSensitivity:
    """Angle error of a design when the printed module deviates from it (seeded MC).

    Each sample moves every hole by an independent normal offset of standard deviation
    ``hole_tolerance_mm`` (along the rib) and the cable length by one of standard
    deviation ``length_tolerance_mm``, and forward-solves the perturbed module
    (:func:`design_sensitivity`). Errors are L2 norms of ``angles - target``, rad.

    Attributes
    ----------
    hole_tolerance_mm, length_tolerance_mm : float
        Standard deviations of the hole-offset and cable-length noise, mm.
    n_samples : int
        Monte Carlo samples.
    seed : int
        Seed of ``numpy.random.default_rng`` for the noise draws.
    median_error, p90_error, mean_error, max_error : float
        Median, 90th percentile, mean and largest error over the samples, rad.
    nominal_error : float
        Error of the design as designed (no noise), rad.
    n_at_limit : int
        Samples whose cable length is at or below the perturbed module's reachable
        range: the shape with every segment at its branch end (rib contact) is used.
    quantile, quantile_error : float
        The quantile the designs were ranked by (0.5: the median) and its error, rad.
    """

    hole_tolerance_mm: float
    length_tolerance_mm: float
    n_samples: int
    seed: int
    median_error: float
    p90_error: float
    mean_error: float
    max_error: float
    nominal_error: float
    n_at_limit: int = 0
    quantile: float = 0.5
    quantile_error: float = math.nan


class DesignStopped(ValueError):
    """A design stopped before it finished (base of the two reasons below).

    Attributes
    ----------
    stage : str
        Step of the design that was running (see :data:`DESIGN_STAGES`).
    fraction : float
        Progress reached, 0 to 1.
    elapsed_s : float
        Wall time from the start of the design to the stop, s.
    """

    def __init__(self, message, stage, fraction, elapsed_s):
        super().__init__(message)
        self.stage = stage
        self.fraction = fraction
        self.elapsed_s = elapsed_s


class DesignCancelled(DesignStopped):
    """``should_stop()`` returned true: the caller cancelled the design."""


class DesignTimedOut(DesignStopped):
    """The design ran past ``time_limit_s`` (attribute ``time_limit_s``, s)."""

    def __init__(self, message, stage, fraction, elapsed_s, time_limit_s):
        super().__init__(message, stage, fraction, elapsed_s)
        self.time_limit_s = time_limit_s


#: Stages reported to ``progress`` in order (``fraction`` never decreases).
DESIGN_STAGES = ('fit target', 'tension tables', 'branch and bound', 'polish', 'verify', 'done')


class _Monitor:
    """Cancel and time-limit checks and progress reports of one design."""

    def __init__(self, should_stop, time_limit_s, progress, started):
        self.should_stop = should_stop
        self.time_limit_s = time_limit_s
        self.deadline = None if time_limit_s is None else started + time_limit_s
        self.progress = progress
        self.started = started
        self.fraction = 0.0
        self.stage = DESIGN_STAGES[0]

    def check(self):
        """Raise DesignCancelled / DesignTimedOut when the design must stop now."""
        if self.should_stop is not None and self.should_stop():
            elapsed = time.perf_counter() - self.started
            raise DesignCancelled(
                f'design cancelled after {elapsed:.3g} s during {self.stage} '
                f'({100 * self.fraction:.0f} % done)', self.stage, self.fraction, elapsed)
        if self.deadline is not None and (now := time.perf_counter()) > self.deadline:
            elapsed = now - self.started
            raise DesignTimedOut(
                f'design exceeded its time limit of {self.time_limit_s:g} s (stopped after '
                f'{elapsed:.3g} s during {self.stage}, {100 * self.fraction:.0f} % done)',
                self.stage, self.fraction, elapsed, self.time_limit_s)

    def report(self, fraction, stage):
        """Record progress (kept monotone), tell the caller, then check for a stop."""
        self.fraction = min(max(float(fraction), self.fraction), 1.0)
        self.stage = stage
        if self.progress is not None:
            self.progress(self.fraction, stage)
        self.check()


def _no_check():
    pass


@dataclasses.dataclass(frozen=True)
class DesignResult:
    """One inverse design and, for the best one, its ranked alternatives.

    Attributes
    ----------
    threading : ndarray, shape (n_ribs,)
        Hole offset per rib, rib 0 first, in mm (positive: right side, -y).
    holes : tuple of str
        Hole name per rib.
    cable_length : float
        Cable length inside the module that produces the shape, in mm.
    angles : ndarray, shape (n_segments,)
        Forward-solved bending angle per segment, rad.
    rib_centers : ndarray, shape (n_ribs, 2)
        Forward-solved rib centres in the module base frame, mm.
    error : float
        L2 norm of ``angles - target_angles``, rad.
    position_error : float
        Largest distance between a rib centre of the design and that of the target
        shape, mm.
    alternatives : tuple of DesignResult
        Next best distinct threadings, best first (empty on the alternatives themselves).
    tension : float
        Cable tension of the design per unit stiffness (the forward solve's multiplier).
    target_angles : ndarray, shape (n_segments,)
        The target (fitted from the target points when those were given), rad.
    fit_error : float
        Largest distance of the fitted target rib centres from the target polyline, mm
        (0 for angle targets).
    lower_bound : float
        Certified lower bound of the error of any design allowed by the constraints, rad.
    n_forward_solves : int
        Calls of ``forward.solve_forward`` made by the design.
    n_tension_nodes : int
        Tensions at which the per-segment angle table was evaluated.
    n_candidates : int
        Threadings refined by the 1-D tension search.
    converged : bool
        True when the branch and bound closed the gap to ``GLOBAL_TOL_RAD``.
    message : str
        Human-readable summary, including any disagreement with the forward solver.
    solve_time : float
        Wall time of the design, s.
    sensitivity : DesignSensitivity or None
        Error under hole-position and cable-length tolerance, when
        ``design_threading`` was given a tolerance (None otherwise).
    """

    threading: np.ndarray
    holes: tuple
    cable_length: float
    angles: np.ndarray
    rib_centers: np.ndarray
    error: float
    position_error: float
    alternatives: tuple = ()
    tension: float = 0.0
    target_angles: np.ndarray | None = None
    fit_error: float = 0.0
    lower_bound: float = 0.0
    n_forward_solves: int = 0
    n_tension_nodes: int = 0
    n_candidates: int = 0
    converged: bool = True
    message: str = ''
    solve_time: float = 0.0
    sensitivity: DesignSensitivity | None = None


def result_to_dict(res):
    """Plain-data (JSON-serialisable) form of a :class:`DesignResult`."""
    def one(d):
        out = {'holes': list(d.holes), 'threading_mm': d.threading.tolist(),
               'cable_length_mm': d.cable_length, 'angles_rad': d.angles.tolist(),
               'rib_centers_mm': d.rib_centers.tolist(), 'error_rad': d.error,
               'position_error_mm': d.position_error, 'tension': d.tension}
        if d.sensitivity is not None:
            # Field names carry the units: tolerances in mm, errors in rad.
            out['sensitivity'] = dataclasses.asdict(d.sensitivity)
        return out
    out = one(res)
    out.update(alternatives=[one(a) for a in res.alternatives], fit_error_mm=res.fit_error,
               target_angles_rad=res.target_angles.tolist(), lower_bound_rad=res.lower_bound,
               converged=res.converged, message=res.message, solve_time_s=res.solve_time,
               n_forward_solves=res.n_forward_solves, n_tension_nodes=res.n_tension_nodes)
    return out
