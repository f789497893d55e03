"""Calibration of the module model from observed rib centres (pure numpy/scipy).

Fits, by :func:`scipy.optimize.least_squares` on the rib-centre distances:

* ``stiffness``: relative stiffness ``k_i`` of every segment but one (the reference
  segment keeps its value: without loads the model is scale-free, only ratios matter);
* ``friction``: one friction coefficient for every hole (:mod:`.friction`);
* ``length_scale`` and ``length_offset``: the encoder scale, the model's cable length
  being ``length_scale * L_observed + length_offset_mm`` (``L_observed`` from the
  commanded or encoder length).

* ``bending_stiffness``: ``K`` (N mm/rad^2). It changes no unloaded shape, so it is
  fitted from observations under gravity or a point load (:mod:`.loads`), the only ones
  that compare a force with ``K``; those observations are solved without friction
  (no solver couples the two yet), so ``friction`` cannot be fitted with them.

Observation model: every observed rib centre (mm, in the module's base frame: rib 0 at
the origin, spine leaving along +x, i.e. the markers registered to the base rib) is the
model's rib centre plus independent Gaussian noise of one standard deviation for x and
y. Rib 0 defines the frame and is left out of the residuals. Missing markers are NaN.
Confidence intervals come from the Jacobian at the solution, ``cov = s^2 (J^T J)^-1``
with ``s^2 = SSR / (m - p)``, and Student's t; they are local (linearised) intervals,
infinite where the data do not determine a parameter (e.g. the stiffness of a segment
that stays straight or at rib contact in every observation).

Input file (YAML or JSON), ``softsnap-model calibrate --data FILE``::

    skeleton: {...}                   # optional, Skeleton.from_dict keys
    observations:
      - threading: "R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3"
        cable_length_mm: 170.0        # the commanded / encoder length
        direction: pull               # optional: pull (default) or release
        rib_centers_mm: [[0, 0], [17.9, -1.2], ...]   # one [x, y] per rib
        gravity_mps2: [0, -9.81, 0]   # optional: gravity in the base frame (m/s^2)
        load_n: [0, 0, 0]             # optional: point load (N) on rib load_rib
        load_rib: -1                  # optional: -1 for the tip
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .forward import reachable_range
from .friction import solve_friction
from .loads import DEFAULT_BENDING_STIFFNESS_NMM, Loads, solve_loaded
from .skeleton import Skeleton

__all__ = ['PARAMETERS', 'Observation', 'CalibrationResult', 'calibrate',
           'load_observations', 'synthetic_observations', 'add_cli']

#: Parameters that can be fitted, with their bounds used by the fit.
PARAMETERS: Mapping[str, tuple[float, float]] = {
    'stiffness': (0.02, 50.0),        # relative k_i (the reference segment excluded)
    'friction': (0.0, 1.5),           # mu, the same at every hole
    'length_scale': (0.5, 2.0),       # model length = scale * observed + offset
    'length_offset': (-100.0, 100.0),  # mm
    'bending_stiffness': (0.1, 10000.0),  # K, N mm/rad^2 (needs loaded observations)
}
#: Default set of fitted parameters.
DEFAULT_FIT = ('stiffness', 'friction', 'length_scale', 'length_offset')
#: Confidence level of the reported intervals.
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Observation:
    """One observed shape.

    Attributes
    ----------
    threading : tuple
        One hole per rib (names or offsets mm).
    cable_length_mm : float
        Observed (commanded or encoder) cable length (mm), before the encoder scale.
    rib_centers_mm : ndarray (n_ribs, 2)
        Observed rib centres (mm) in the base frame; NaN for a missing marker.
    direction : str
        'pull' (reached by shortening) or 'release' (by lengthening).
    gravity_mps2, load_n : tuple of 3 float
        Gravity (m/s^2) and a point load (N) in the module base frame while the shape
        was observed (:class:`~softsnap_model.loads.Loads`); zero by default.
    load_rib : int
        Rib carrying the point load (-1: the tip).
    """

    threading: tuple
    cable_length_mm: float
    rib_centers_mm: np.ndarray
    direction: str = 'pull'
    gravity_mps2: tuple = (0.0, 0.0, 0.0)
    load_n: tuple = (0.0, 0.0, 0.0)
    load_rib: int = -1

    def __post_init__(self):
        if self.direction not in ('pull', 'release'):
            raise ValueError(f"direction must be 'pull' or 'release', got {self.direction!r}")
        L = self.cable_length_mm
        if isinstance(L, bool) or not isinstance(L, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(L)) or float(L) <= 0:
            raise ValueError(f'cable_length_mm must be finite and > 0, got {L!r}')
        object.__setattr__(self, 'cable_length_mm', float(L))
        t = self.threading.split() if isinstance(self.threading, str) else self.threading
        object.__setattr__(self, 'threading', tuple(t))
        p = np.asarray(self.rib_centers_mm, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f'rib_centers_mm must be (n_ribs, 2), got shape {p.shape}')
        if np.any(np.isinf(p)):
            raise ValueError('rib_centers_mm must be finite (NaN marks a missing marker)')
        object.__setattr__(self, 'rib_centers_mm', p)
        # Validated (and made plain tuples) by Loads itself.
        loads = self.loads(DEFAULT_BENDING_STIFFNESS_NMM)
        object.__setattr__(self, 'gravity_mps2', loads.gravity_mps2)
        object.__setattr__(self, 'load_n', loads.load_n)
        object.__setattr__(self, 'load_rib', loads.load_rib)

    def loads(self, bending_stiffness_nmm: float) -> Loads:
        """The observation's loads with a bending stiffness ``K`` (N mm/rad^2)."""
        return Loads(gravity_mps2=tuple(self.gravity_mps2), load_n=tuple(self.load_n),
                     load_rib=self.load_rib, bending_stiffness_nmm=bending_stiffness_nmm)

    @property
    def loaded(self) -> bool:
        """True when gravity or the load has an in-plane component."""
        return not self.loads(DEFAULT_BENDING_STIFFNESS_NMM).is_zero


@dataclass(frozen=True)
class CalibrationResult:
    """Result of :func:`calibrate`.

    Attributes
    ----------
    names : tuple of str
        Fitted parameter names (``stiffness[i]``, ``friction``, ``length_scale``,
        ``length_offset_mm``).
    values, stderr, ci_low, ci_high : ndarray
        Estimates, standard errors and the ``CONFIDENCE`` interval (inf where the data do
        not determine the parameter).
    stiffness : ndarray (n_segments,)
        All relative stiffnesses (the reference segment's as given).
    reference_segment : int
    friction : float
    length_scale : float
    length_offset_mm : float
    rmse_mm : float
        Root mean square of the rib-centre coordinate residuals (mm) at the solution.
    rms_distance_mm : float
        Root mean square rib-centre distance (mm), ``sqrt(2) * rmse_mm``.
    n_points : int
        Observed rib centres used (rib 0 excluded).
    dof : int
        Residual degrees of freedom ``2 n_points - n_parameters``.
    nfev : int
    converged : bool
        ``least_squares`` met a tolerance and every model solve converged.
    message : str
    skeleton : Skeleton
        The skeleton with the fitted stiffness.
    bending_stiffness_nmm : float
        ``K`` (N mm/rad^2): fitted, or the start value used for loaded observations.
    """

    names: tuple
    values: np.ndarray
    stderr: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    stiffness: np.ndarray
    reference_segment: int
    friction: float
    length_scale: float
    length_offset_mm: float
    rmse_mm: float
    rms_distance_mm: float
    n_points: int
    dof: int
    nfev: int
    converged: bool
    message: str
    skeleton: Skeleton
    bending_stiffness_nmm: float = DEFAULT_BENDING_STIFFNESS_NMM

    def to_dict(self) -> dict:
        """Plain JSON-able form (infinite bounds as None)."""
        def clean(v):
            return [float(x) if math.isfinite(x) else None for x in np.asarray(v, float)]
        return {
            'parameters': {n: {'value': float(v), 'stderr': s, 'ci_low': lo, 'ci_high': hi}
                           for n, v, s, lo, hi in zip(self.names, self.values,
                                                       clean(self.stderr), clean(self.ci_low),
                                                       clean(self.ci_high))},
            'confidence': CONFIDENCE,
            'stiffness': self.stiffness.tolist(), 'reference_segment': self.reference_segment,
            'friction': self.friction, 'length_scale': self.length_scale,
            'length_offset_mm': self.length_offset_mm,
            'bending_stiffness_nmm': self.bending_stiffness_nmm, 'rmse_mm': self.rmse_mm,
            'rms_distance_mm': self.rms_distance_mm, 'n_points': self.n_points,
            'dof': self.dof, 'nfev': self.nfev, 'converged': self.converged,
            'message': self.message}


# ----------------------------------------------------------------------------------------
# Model evaluation
# ----------------------------------------------------------------------------------------
def _with_stiffness(skeleton: Skeleton, k) -> Skeleton:
    # dataclasses.replace keeps every other field (and any added later, e.g. rib thickness).
    return dataclasses.replace(skeleton, stiffness=tuple(float(v) for v in k))


def model_rib_centers(skeleton: Skeleton, obs: Observation, friction: float,
                      length_scale: float = 1.0, length_offset_mm: float = 0.0,
                      bending_stiffness_nmm: float = DEFAULT_BENDING_STIFFNESS_NMM):
    """Model rib centres (mm) for one observation; returns ``(centres, converged)``.

    A loaded observation (gravity or a load in the plane) is solved by
    :func:`~softsnap_model.loads.solve_loaded` with ``K``, without friction.

    The model length is clamped into the reachable range (just above its minimum), so
    the fit sees a finite, continuous residual where a trial parameter set cannot reach
    the observed length.
    """
    L = length_scale * obs.cable_length_mm + length_offset_mm
    lo, hi = reachable_range(skeleton, obs.threading)
    L = max(L, lo + 1e-6 * (hi - lo))
    if obs.loaded:
        res = solve_loaded(skeleton, obs.threading, L, obs.loads(bending_stiffness_nmm))
    else:
        res = solve_friction(skeleton, obs.threading, L, friction, obs.direction)
    return res.rib_centers, res.converged


class _Problem:
    def __init__(self, skeleton, observations, fit, reference_segment, initial):
        self.skeleton = skeleton
        self.obs = list(observations)
        self.fit = tuple(fit)
        self.ref = reference_segment
        n = skeleton.n_segments
        self.free_k = [i for i in range(n) if i != reference_segment]
        self.k0 = skeleton.stiffness_array
        self.start = dict(friction=0.1 if 'friction' in self.fit else 0.0,
                          length_scale=1.0, length_offset=0.0,
                          bending_stiffness=DEFAULT_BENDING_STIFFNESS_NMM)
        self.start.update(initial or {})
        names, x0, lo, hi = [], [], [], []
        for p in self.fit:
            b = PARAMETERS[p]
            if p == 'stiffness':
                for i in self.free_k:
                    names.append(f'stiffness[{i}]')
                    x0.append(float(np.clip(self.k0[i], *b)))
                    lo.append(b[0])
                    hi.append(b[1])
            else:
                names.append({'length_offset': 'length_offset_mm',
                              'bending_stiffness': 'bending_stiffness_nmm'}.get(p, p))
                x0.append(float(np.clip(self.start[p], *b)))
                lo.append(b[0])
                hi.append(b[1])
        self.names, self.x0 = tuple(names), np.array(x0)
        self.lo, self.hi = np.array(lo), np.array(hi)
        self.masks = [np.isfinite(o.rib_centers_mm[1:]).all(axis=1) for o in self.obs]
        self.n_points = int(sum(m.sum() for m in self.masks))
        self.all_converged = True

    def unpack(self, x):
        k = self.k0.copy()
        vals = {name: self.start[name] for name in
                ('friction', 'length_scale', 'length_offset', 'bending_stiffness')}
        j = 0
        for p in self.fit:
            if p == 'stiffness':
                k[self.free_k] = x[j:j + len(self.free_k)]
                j += len(self.free_k)
            else:
                vals[p] = float(x[j])
                j += 1
        return k, vals

    def residuals(self, x):
        k, v = self.unpack(x)
        sk = _with_stiffness(self.skeleton, k)
        out = []
        ok = True
        for o, m in zip(self.obs, self.masks):
            c, conv = model_rib_centers(sk, o, v['friction'], v['length_scale'],
                                        v['length_offset'], v['bending_stiffness'])
            ok &= conv
            out.append((c[1:] - o.rib_centers_mm[1:])[m].ravel())
        self.all_converged = ok
        return np.concatenate(out)


def calibrate(skeleton: Skeleton, observations: Sequence[Observation],
              fit: Sequence[str] = DEFAULT_FIT, *, reference_segment: int = 0,
              initial: Mapping[str, float] | None = None,
              max_nfev: int = 200) -> CalibrationResult:
    """Fit stiffness ratios, friction and encoder scale to observed rib centres.

    Parameters
    ----------
    skeleton : Skeleton
        Geometry; its ``stiffness`` is the start (and the reference segment's value).
    observations : sequence of Observation
        Several cable lengths and threadings give the parameters apart (friction acts
        through each threading's wrap angles, stiffness through each segment's bend).
    fit : sequence of str
        Subset of :data:`PARAMETERS`; the others keep their start values.
    reference_segment : int
        Segment whose stiffness is held fixed (sets the scale).
    initial : mapping, optional
        Start values for 'friction' (default 0.1), 'length_scale' (1),
        'length_offset' (0 mm), 'bending_stiffness' (the default K, N mm/rad^2).
    max_nfev : int
        Cap on residual evaluations of ``least_squares``.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    ValueError
        No observations, unknown parameter names, a bad reference segment, a threading
        or rib count not matching the skeleton, fewer residuals than parameters,
        ``bending_stiffness`` without a loaded observation, or friction together with
        loaded observations.
    """
    if not isinstance(skeleton, Skeleton):
        raise ValueError(f'skeleton must be a Skeleton, got {type(skeleton).__name__}')
    observations = list(observations)
    if not observations:
        raise ValueError('calibrate needs at least one observation, got none')
    unknown = [p for p in fit if p not in PARAMETERS]
    if unknown or not fit:
        raise ValueError(f'unknown or empty parameters to fit {list(fit)!r}; allowed: '
                         f'{sorted(PARAMETERS)}')
    n = skeleton.n_segments
    if isinstance(reference_segment, bool) or not isinstance(reference_segment, int) \
            or not 0 <= reference_segment < n:
        raise ValueError(f'reference_segment must be an integer in [0, {n - 1}], got '
                         f'{reference_segment!r}')
    for i, o in enumerate(observations):
        if not isinstance(o, Observation):
            raise ValueError(f'observation {i}: expected an Observation, got '
                             f'{type(o).__name__}')
        skeleton.threading_mm(o.threading)
        if o.rib_centers_mm.shape[0] != skeleton.n_ribs:
            raise ValueError(f'observation {i}: expected {skeleton.n_ribs} rib centres, got '
                             f'{o.rib_centers_mm.shape[0]}')
    loaded = [i for i, o in enumerate(observations) if o.loaded]
    if 'bending_stiffness' in fit and not loaded:
        raise ValueError('bending_stiffness changes no unloaded shape: fitting it needs '
                         'observations under gravity or a load (gravity_mps2, load_n)')
    friction_start = (initial or {}).get('friction', 0.1 if 'friction' in fit else 0.0)
    if loaded and ('friction' in fit or friction_start != 0.0):
        raise ValueError(f'observations {loaded} are loaded and are solved without friction '
                         '(no solver couples gravity/loads with friction yet): do not fit '
                         'or set friction with them')
    from scipy.optimize import least_squares
    from scipy.stats import t as student_t
    prob = _Problem(skeleton, observations, fit, reference_segment, initial)
    m, p = 2 * prob.n_points, prob.x0.size
    if m <= p:
        raise ValueError(f'{m} residuals (2 per observed rib centre, rib 0 excluded) for '
                         f'{p} parameters: need more observations')
    sol = least_squares(prob.residuals, prob.x0, bounds=(prob.lo, prob.hi), method='trf',
                        x_scale='jac', diff_step=1e-6, max_nfev=max_nfev,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10)
    r = prob.residuals(sol.x)       # also refreshes the convergence flag at the solution
    ssr = float(r @ r)
    dof = m - p
    s2 = ssr / dof
    J = sol.jac
    # Covariance by the SVD, infinite variance along directions the data do not fix.
    _, sv, vt = np.linalg.svd(J, full_matrices=False)
    tol = sv.max() * max(J.shape) * np.finfo(float).eps if sv.size else 0.0
    with np.errstate(divide='ignore'):
        inv = np.where(sv > tol, 1.0 / np.where(sv > tol, sv, 1.0) ** 2, np.inf)
    var = np.empty(p)
    for j in range(p):
        w = vt[:, j] ** 2
        var[j] = float(np.sum(np.where(w > 0, w * inv, 0.0))) * s2
    stderr = np.sqrt(var)
    q = float(student_t.ppf(0.5 + 0.5 * CONFIDENCE, dof))
    k, v = prob.unpack(sol.x)
    rmse = math.sqrt(ssr / m)
    ok = bool(sol.success) and prob.all_converged
    msg = sol.message if prob.all_converged else \
        sol.message + '; some model solves did not converge at the solution'
    return CalibrationResult(
        names=prob.names, values=sol.x.copy(), stderr=stderr, ci_low=sol.x - q * stderr,
        ci_high=sol.x + q * stderr, stiffness=k, reference_segment=reference_segment,
        friction=v['friction'], length_scale=v['length_scale'],
        length_offset_mm=v['length_offset'], rmse_mm=rmse,
        rms_distance_mm=math.sqrt(2.0) * rmse, n_points=prob.n_points, dof=dof,
        nfev=int(sol.nfev), converged=ok, message=str(msg),
        skeleton=_with_stiffness(skeleton, k), bending_stiffness_nmm=v['bending_stiffness'])


# ----------------------------------------------------------------------------------------
# Data: files and synthetic observations
# ----------------------------------------------------------------------------------------
def load_observations(path) -> tuple[Skeleton, list]:
    """Read a calibration file (YAML or JSON, format in the module docstring).

    Returns ``(skeleton, observations)``; the skeleton is ``Skeleton()`` unless the file
    has a ``skeleton`` mapping.
    """
    import yaml
    data = yaml.safe_load(Path(path).read_text())
    if not isinstance(data, Mapping) or 'observations' not in data:
        raise ValueError(f'{path}: expected a mapping with an "observations" list')
    unknown = set(data) - {'skeleton', 'observations'}
    if unknown:
        raise ValueError(f'{path}: unknown keys {sorted(unknown)}; allowed: '
                         f'["observations", "skeleton"]')
    skeleton = Skeleton.from_dict(data['skeleton']) if data.get('skeleton') else Skeleton()
    obs = []
    items = data['observations']
    if not isinstance(items, list) or not items:
        raise ValueError(f'{path}: "observations" must be a non-empty list')
    for i, item in enumerate(items):
        if not isinstance(item, Mapping):
            raise ValueError(f'{path}: observation {i} must be a mapping, got {item!r}')
        extra = set(item) - {'threading', 'cable_length_mm', 'direction', 'rib_centers_mm',
                             'gravity_mps2', 'load_n', 'load_rib'}
        if extra:
            raise ValueError(f'{path}: observation {i}: unknown keys {sorted(extra)}')
        try:
            rc = np.array([[np.nan if v is None else v for v in row]
                           for row in item['rib_centers_mm']], dtype=float)
            obs.append(Observation(threading=item['threading'],
                                   cable_length_mm=item['cable_length_mm'],
                                   rib_centers_mm=rc,
                                   direction=item.get('direction', 'pull'),
                                   gravity_mps2=tuple(item.get('gravity_mps2', (0.0, 0.0, 0.0))),
                                   load_n=tuple(item.get('load_n', (0.0, 0.0, 0.0))),
                                   load_rib=item.get('load_rib', -1)))
        except KeyError as exc:
            raise ValueError(f'{path}: observation {i}: missing key {exc}') from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{path}: observation {i}: {exc}') from None
    return skeleton, obs


def synthetic_observations(skeleton: Skeleton, threadings, contractions_mm, *,
                           friction: float = 0.0, length_scale: float = 1.0,
                           length_offset_mm: float = 0.0, noise_mm: float = 0.0,
                           seed: int = 0, directions=('pull',),
                           gravity_mps2=(0.0, 0.0, 0.0), load_n=(0.0, 0.0, 0.0),
                           load_rib: int = -1,
                           bending_stiffness_nmm: float = DEFAULT_BENDING_STIFFNESS_NMM) -> list:
    """Observations generated by the model itself (for tests and examples).

    For every threading, contraction (mm from the model's straight length) and
    direction, the model shape with the given parameters plus Gaussian noise
    (``noise_mm`` per coordinate, seeded). The recorded length is the one an encoder
    with that scale and offset would report: ``(L_model - offset) / scale``. With gravity
    or a load in the plane the shapes come from :func:`~softsnap_model.loads.solve_loaded`
    with ``bending_stiffness_nmm`` (and no friction).
    """
    rng = np.random.default_rng(seed)
    out = []
    for t in threadings:
        t = tuple(t.split()) if isinstance(t, str) else tuple(t)
        straight = skeleton.straight_length_mm(t)
        for c in contractions_mm:
            for direction in directions:
                L = straight - float(c)
                template = Observation(t, L, np.zeros((skeleton.n_ribs, 2)), direction,
                                       tuple(gravity_mps2), tuple(load_n), load_rib)
                if template.loaded:
                    res = solve_loaded(skeleton, t, L, template.loads(bending_stiffness_nmm))
                else:
                    res = solve_friction(skeleton, t, L, friction, direction)
                if not res.converged:
                    raise ValueError(f'model did not converge for {t} at {L} mm: '
                                     f'{res.message}')
                pts = res.rib_centers + noise_mm * rng.standard_normal(res.rib_centers.shape)
                pts[0] = 0.0
                out.append(dataclasses.replace(
                    template, cable_length_mm=(L - length_offset_mm) / length_scale,
                    rib_centers_mm=pts))
    return out


def observations_to_dict(observations, skeleton: Skeleton | None = None) -> dict:
    """Plain data form accepted by :func:`load_observations` (e.g. to write a file)."""
    data = {'observations': [
        {'threading': ' '.join(str(h) for h in o.threading),
         'cable_length_mm': round(o.cable_length_mm, 6), 'direction': o.direction,
         'rib_centers_mm': [[None if not math.isfinite(v) else round(float(v), 4)
                             for v in row] for row in o.rib_centers_mm],
         **({'gravity_mps2': list(o.gravity_mps2), 'load_n': list(o.load_n),
             'load_rib': o.load_rib} if o.loaded else {})}
        for o in observations]}
    if skeleton is not None:
        data['skeleton'] = skeleton.to_dict()
    return data


# ----------------------------------------------------------------------------------------
# Command line: ``softsnap-model calibrate``
# ----------------------------------------------------------------------------------------
def _cmd_calibrate(args, skeleton) -> dict:
    file_skeleton, obs = load_observations(args.data)
    if args.skeleton is None:
        skeleton = file_skeleton
    fit = tuple(p.strip() for p in args.fit.split(',') if p.strip())
    initial = {}
    if args.friction is not None:
        initial['friction'] = args.friction
    elif any(o.loaded for o in obs) and 'friction' not in fit:
        initial['friction'] = 0.0   # loaded observations are solved without friction
    res = calibrate(skeleton, obs, fit, reference_segment=args.reference_segment,
                    initial=initial, max_nfev=args.max_nfev)
    out = res.to_dict()
    out['n_observations'] = len(obs)
    return out


def add_cli(subparsers) -> None:
    """Register ``calibrate`` with the ``softsnap-model`` command line."""
    p = subparsers.add_parser(
        'calibrate', help='fit stiffness ratios, friction and encoder scale to observed '
                          'rib centres (YAML/JSON file)')
    p.add_argument('--data', required=True, metavar='FILE',
                   help='observations (format: softsnap_model.calibration docstring)')
    p.add_argument('--fit', default=','.join(DEFAULT_FIT),
                   help=f'comma-separated parameters among {sorted(PARAMETERS)} '
                        f'(default: all)')
    p.add_argument('--reference-segment', type=int, default=0,
                   help='segment whose stiffness stays fixed (default 0)')
    p.add_argument('--friction', type=float, default=None,
                   help='start (or fixed, if not fitted) friction coefficient (default 0.1)')
    p.add_argument('--max-nfev', type=int, default=200,
                   help='cap on model evaluations of the fit')
    p.set_defaults(handler=_cmd_calibrate)
