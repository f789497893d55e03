"""Gravity and point loads: a coupled quasi-static solve (pure numpy).

Model. With the module's weight and a point load the shape minimises the potential
energy (N mm)::

    E(a) = K sum_i k_i a_i^2  -  sum_j w_j . p_j(a)

subject to the cable ``L(a) = sum_i L(a_i; d_i, d_{i+1}) <= L_target`` (the cable
cannot stretch; it may go slack) and the rib contact bounds ``|a_i| <= a_c``
(``Skeleton.contact_angle_rad``). ``p_j`` is the centre of rib ``j`` (mm, module base
frame, :func:`softsnap_model.geometry.rib_centers`) and ``w_j`` the in-plane force on
it (N): its weight ``m_j g`` plus the point load on the loaded rib. ``K`` (N mm/rad^2)
is the bending stiffness of a segment, ``k_i`` the skeleton's relative stiffness.
Rib 0 is clamped to the motor box at the origin, so neither its weight nor the motor
box's does work: they load the mount, not the skeleton.

Only the components in the module's bending plane (x, y of the base frame) act; the
out-of-plane component (z) would twist or bend the skeleton across its 9 mm thickness,
which the planar model does not represent, and is ignored.

Unlike the unloaded model these terms couple the segments (a weight at the tip bends
every segment), so the solve is a Newton iteration on the full KKT system with an
active set for the contact bounds and the cable (taut with tension ``lambda >= 0``, or
slack with ``L(a) <= L_target``), started from the unloaded answer of
:func:`softsnap_model.forward.solve_forward` and applying the load in steps when a
direct step fails (load continuation). The answer is the equilibrium reached by
applying the loads gradually at a fixed cable length to the unloaded shape.

Accuracy contract (on ``converged``): ``|L(a) - L_target| <= CONSTRAINT_TOL_MM`` when
taut, ``L(a) - L_target <= CONSTRAINT_TOL_MM`` when slack; stationarity
``max_i |dLagrangian/da_i| / (2 K k_i) <= STATIONARITY_TOL_RAD`` over the segments not
at contact; multipliers of the correct sign (tension ``>= 0``, contact forces pushing
outward); the Lagrangian Hessian positive definite on the tangent space of the active
constraints (``is_minimum``). Otherwise ``converged`` is False with a message; nothing
is silently returned as an answer.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from .forward import solve_forward
from .geometry import cable_path, half_angle_functions, rib_centers, segment_length_derivatives
from .skeleton import Skeleton

__all__ = [
    'CONSTRAINT_TOL_MM', 'STATIONARITY_TOL_RAD', 'MAX_ITER', 'STANDARD_GRAVITY_MPS2',
    'DEFAULT_BENDING_STIFFNESS_NMM', 'DEFAULT_RIB_MASS_KG', 'DEFAULT_END_RIB_MASS_KG',
    'MOTOR_BOX_MASS_KG_ESTIMATE', 'Loads', 'LoadedResult', 'solve_loaded', 'loaded_energy',
]

#: Cable contract (mm): ``|L(a) - L_target|`` when taut, ``L(a) - L_target`` when slack.
CONSTRAINT_TOL_MM = 1e-9
#: Stationarity contract (rad): ``max |dLagrangian/da_i| / (2 K k_i)`` over free segments.
STATIONARITY_TOL_RAD = 1e-10
#: Cap on Newton iterations per load step.
MAX_ITER = 60
#: Cap on load-continuation steps.
MAX_LOAD_STEPS = 64
#: Standard gravity (m/s^2).
STANDARD_GRAVITY_MPS2 = 9.80665

#: Bending stiffness K (N mm/rad^2, energy ``K a^2`` per segment) estimated for the
#: authors' skeleton: TPU 95A, E ~ 26 MPa (typical data-sheet tensile modulus; printed
#: 100 % infill), spine rod 3 mm (in plane) x 9 mm in the CAD, so EI = 26 * 9 * 3^3 / 12
#: = 527 N mm^2, bending over the free rod s - t = 15 mm between two ribs:
#: K = EI / (2 (s - t)) = 17.6 N mm/rad^2. Uncertain by a factor of 2-3 (TPU grades and
#: print settings vary): measure it (docs/model.md, "Physics levels") or calibrate it.
DEFAULT_BENDING_STIFFNESS_NMM = 17.6
#: Mass lumped at an interior rib (kg): the rib (25 x 3 x 9 mm less six 2 mm holes,
#: 618 mm^3) plus half of each adjacent spine rod (363 mm^3 per 15 mm rod), from the
#: CAD volume (11410 mm^3 in all) at the density of TPU, 1.21 g/cm^3: 1.19 g.
DEFAULT_RIB_MASS_KG = 1.187e-3
#: Mass lumped at an end rib (kg): the rib plus half of one rod, 0.97 g.
DEFAULT_END_RIB_MASS_KG = 0.967e-3
#: Motor box (motor, PCB, battery, PLA shell): estimate ~25 g (N20 gear motor ~10 g,
#: 200 mAh cell ~5 g, PCB ~3 g, shell 3.4 cm^3 of PLA at 20-30 % infill plus walls ~5 g).
#: It sits at the clamped base (the paper's experiments fix the skeleton's end attached
#: to the body case), so it does not enter the shape; kept for documentation.
MOTOR_BOX_MASS_KG_ESTIMATE = 25e-3

# A step that would move any angle by more than this (rad) is shortened: Newton from far
# away on a nonconvex energy must not jump to another branch.
_MAX_STEP_RAD = 0.25
# Smallest load-continuation step (fraction of the full load) before giving up.
_MIN_LOAD_STEP = 1.0 / 4096


@dataclass(frozen=True)
class Loads:
    """Gravity and a point load acting on one module (SI units at the interface).

    Parameters
    ----------
    gravity_mps2 : sequence of 3 float
        Gravity vector in the module base frame (m/s^2): x along the straight spine,
        y to the module's left (the "L" side), z out of the bending plane. ``(0, -9.81,
        0)``: lying on its right side; ``(9.81, 0, 0)``: hanging down from its base
        (tip below); ``(-9.81, 0, 0)``: raised straight up (tip above, it may buckle);
        ``(0, 0, -9.81)``: lying flat on a table (no effect).
    bending_stiffness_nmm : float
        ``K`` (N mm/rad^2), > 0: the energy of segment ``i`` is ``K k_i a_i^2``.
    load_n : sequence of 3 float
        Point force on a rib centre in the base frame (N); z is ignored.
    load_rib : int
        Rib carrying the point load: 1 .. n_ribs - 1, or -1 for the tip (last rib).
        (Rib 0 is clamped.)
    rib_masses_kg : sequence of float, optional
        Mass lumped at each rib centre (kg), rib 0 first (``n_ribs`` values). None: the
        authors' skeleton estimate, ``DEFAULT_END_RIB_MASS_KG`` at both ends and
        ``DEFAULT_RIB_MASS_KG`` elsewhere.
    """

    gravity_mps2: tuple = (0.0, 0.0, 0.0)
    bending_stiffness_nmm: float = DEFAULT_BENDING_STIFFNESS_NMM
    load_n: tuple = (0.0, 0.0, 0.0)
    load_rib: int = -1
    rib_masses_kg: tuple | None = None

    def __post_init__(self):
        for name in ('gravity_mps2', 'load_n'):
            v = getattr(self, name)
            try:
                arr = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f'{name} must be 3 numbers, got {v!r}') from None
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise ValueError(f'{name} must be 3 finite numbers, got {v!r}')
            object.__setattr__(self, name, tuple(float(x) for x in arr))
        k = self.bending_stiffness_nmm
        if isinstance(k, bool) or not isinstance(k, numbers.Real) or not math.isfinite(k) \
                or k <= 0.0:
            raise ValueError(f'bending_stiffness_nmm must be finite and > 0 N mm/rad^2, '
                             f'got {k!r}')
        object.__setattr__(self, 'bending_stiffness_nmm', float(k))
        r = self.load_rib
        if isinstance(r, bool) or not isinstance(r, numbers.Integral) or (r < 1 and r != -1):
            raise ValueError(f'load_rib must be -1 (tip) or a rib index >= 1, got {r!r}')
        object.__setattr__(self, 'load_rib', int(r))
        if self.rib_masses_kg is not None:
            try:
                m = np.asarray(self.rib_masses_kg, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f'rib_masses_kg must be numbers, got '
                                 f'{self.rib_masses_kg!r}') from None
            if m.ndim != 1 or not np.all(np.isfinite(m)) or np.any(m < 0.0):
                raise ValueError(f'rib_masses_kg must be finite masses >= 0 kg, got '
                                 f'{self.rib_masses_kg!r}')
            object.__setattr__(self, 'rib_masses_kg', tuple(float(x) for x in m))

    @property
    def is_zero(self) -> bool:
        """True when no in-plane force acts (the unloaded model applies exactly)."""
        g_in = self.gravity_mps2[0] != 0.0 or self.gravity_mps2[1] != 0.0
        f_in = self.load_n[0] != 0.0 or self.load_n[1] != 0.0
        return not (g_in and self._any_mass()) and not f_in

    def _any_mass(self) -> bool:
        return self.rib_masses_kg is None or any(m > 0.0 for m in self.rib_masses_kg[1:])

    def masses_kg(self, n_ribs: int) -> np.ndarray:
        """Mass at each rib (kg), shape (n_ribs,)."""
        if self.rib_masses_kg is None:
            m = np.full(n_ribs, DEFAULT_RIB_MASS_KG)
            m[0] = m[-1] = DEFAULT_END_RIB_MASS_KG
            return m
        if len(self.rib_masses_kg) != n_ribs:
            raise ValueError(f'expected {n_ribs} rib masses (one per rib), got '
                             f'{len(self.rib_masses_kg)}')
        return np.array(self.rib_masses_kg)

    def rib_forces_n(self, n_ribs: int) -> np.ndarray:
        """In-plane force on each rib centre (N), shape (n_ribs, 2): weight + point load."""
        if self.load_rib != -1 and self.load_rib >= n_ribs:
            raise ValueError(f'load_rib {self.load_rib} is beyond the tip; allowed 1..'
                             f'{n_ribs - 1} or -1 (tip)')
        w = self.masses_kg(n_ribs)[:, None] * np.array(self.gravity_mps2[:2])[None, :]
        w[self.load_rib if self.load_rib != -1 else n_ribs - 1] += self.load_n[:2]
        return w


@dataclass(frozen=True)
class LoadedResult:
    """Answer of :func:`solve_loaded` (mm, rad, N, N mm).

    Attributes
    ----------
    angles : ndarray (n_segments,)
        Bending angles (rad).
    rib_centers, cable_path : ndarray (n_ribs, 2)
        Rib centres and threaded holes (mm, module base frame).
    tension_n : float
        Cable tension (N); 0 when slack.
    slack : bool
        True when the cable is slack (``L(a) < L_target`` and zero tension).
    at_contact : ndarray of bool (n_segments,)
        Segments held at the rib-contact angle.
    energy_nmm : float
        ``E(a)`` (N mm): bending energy minus the work of the forces.
    cable_length_mm : float
        ``L(a)`` (mm), the hole-to-hole length of the shape.
    converged : bool
        True only when the accuracy contract holds (module docstring).
    constraint_residual_mm, stationarity_residual_rad : float
        Measured residuals (see the contract).
    min_curvature : float
        Smallest eigenvalue of the reduced Lagrangian Hessian (N mm/rad^2); > 0 at a
        strict local minimum.
    is_minimum : bool
        ``min_curvature > 0``.
    iterations : int
        Newton iterations over all load steps.
    load_steps : int
        Load-continuation steps taken (1: the full load in one step).
    message : str
        Why the solve stopped.
    """

    angles: np.ndarray
    rib_centers: np.ndarray
    cable_path: np.ndarray
    tension_n: float
    slack: bool
    at_contact: np.ndarray
    energy_nmm: float
    cable_length_mm: float
    converged: bool
    constraint_residual_mm: float
    stationarity_residual_rad: float
    min_curvature: float
    is_minimum: bool
    iterations: int
    load_steps: int
    message: str


def _chord_factor(a):
    """``f(a) = sinc(a/2)`` (chord over arc) and its first two derivatives."""
    f0, f1, _ = half_angle_functions(0.5 * a)
    return f0, -0.25 * a * f1, 0.25 * (2.0 * f1 - f0)


class _Problem:
    """Energy, cable and their derivatives for one skeleton, threading and rib forces."""

    def __init__(self, skeleton: Skeleton, d: np.ndarray, forces: np.ndarray, K: float,
                 target: float):
        n = skeleton.n_segments
        self.n, self.d, self.s = n, d, skeleton.spacing_mm
        self.k2 = 2.0 * K * skeleton.stiffness_array          # 2 K k_i
        self.target = target
        self.a_max = skeleton.contact_angle_rad
        # W_i: total force on the ribs beyond segment i (ribs i+1..n), (n, 2).
        self.W_full = np.cumsum(forces[::-1], axis=0)[::-1][1:]
        # beta[k, i] = d phi_k / d a_i for the chord direction phi_k = sum_{m<k} a_m + a_k/2.
        self.beta = np.tril(np.ones((n, n)), -1) + 0.5 * np.eye(n)

    def evaluate(self, a, tau):
        """Gradient and Hessian of E at load fraction tau; cable L, L', L''. (E itself is
        reported from the geometry, :func:`loaded_energy`: Newton needs only these.)"""
        s, beta = self.s, self.beta
        W = tau * self.W_full
        f, fp, fpp = _chord_factor(a)
        phi = beta @ a
        u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        c = np.einsum('ij,ij->i', W, u)                         # W_k . u(phi_k)
        dd = W[:, 1] * u[:, 0] - W[:, 0] * u[:, 1]              # W_k . J u(phi_k)
        grad = self.k2 * a - s * fp * c - beta.T @ (s * f * dd)
        cross = (s * fp * dd)[:, None] * beta                   # [i, l] = s f'_i d_i beta_il
        hess = (np.diag(self.k2 - s * fpp * c) - cross - cross.T
                + beta.T @ ((s * f * c)[:, None] * beta))
        L, Lp, Lpp = segment_length_derivatives(a, self.d[:-1], self.d[1:], s)
        return grad, hess, float(np.sum(L)), Lp, Lpp


def loaded_energy(skeleton: Skeleton, angles_rad, loads: Loads) -> float:
    """``E(a)`` (N mm) of a shape: ``K sum k_i a_i^2 - sum_j w_j . p_j(a)``."""
    a = np.asarray(angles_rad, dtype=float)
    w = loads.rib_forces_n(skeleton.n_ribs)
    p = rib_centers(a, skeleton.spacing_mm)
    return float(loads.bending_stiffness_nmm * skeleton.stiffness_array @ (a * a)
                 - np.sum(w * p))


def _reduced_hessian_min_eig(H, free, g, taut):
    """Smallest eigenvalue of H on {da: da_i = 0 off ``free``, g . da = 0 if taut}."""
    idx = np.flatnonzero(free)
    if idx.size == 0:
        return math.inf
    Hf = H[np.ix_(idx, idx)]
    if taut:
        gf = g[idx]
        norm = np.linalg.norm(gf)
        if norm == 0.0:
            return float(np.min(np.linalg.eigvalsh(Hf)))
        # Orthonormal basis of the complement of gf: a Householder reflection's columns.
        v = gf / norm
        e = np.zeros_like(v)
        e[0] = 1.0
        w = v - e if v[0] <= 0 else v + e
        Q = np.eye(idx.size) - 2.0 * np.outer(w, w) / (w @ w)
        Z = Q[:, 1:]
        if Z.shape[1] == 0:
            return math.inf
        Hf = Z.T @ Hf @ Z
    return float(np.min(np.linalg.eigvalsh(0.5 * (Hf + Hf.T))))


def _newton(prob: _Problem, a, lam, active, taut, tau, max_iter):
    """Active-set Newton on the KKT system at load fraction ``tau``.

    ``active`` is an int array: 0 free, +1/-1 held at +a_c/-a_c. Returns
    (a, lam, active, taut, iterations, status, residuals).
    """
    n, a_max = prob.n, prob.a_max
    a = a.copy()
    active = active.copy()
    it = 0
    for _ in range(4 * n + 8):           # active-set changes
        for _ in range(max_iter):
            grad, H, L, Lp, Lpp = prob.evaluate(a, tau)
            free = active == 0
            lam_eff = lam if taut else 0.0
            r = grad + lam_eff * Lp
            Ht = H + lam_eff * np.diag(Lpp)
            stat = np.max(np.abs(r[free]) / prob.k2[free], initial=0.0)
            cres = L - prob.target
            # Slack: a stretched path is settled by the active-set check below.
            ok_c = abs(cres) <= CONSTRAINT_TOL_MM if taut else True
            if stat <= STATIONARITY_TOL_RAD and ok_c:
                break
            idx = np.flatnonzero(free)
            if idx.size == 0 and not taut:
                break
            it += 1
            m = idx.size
            if taut:
                A = np.zeros((m + 1, m + 1))
                A[:m, :m] = Ht[np.ix_(idx, idx)]
                A[:m, m] = A[m, :m] = Lp[idx]
                rhs = -np.concatenate([r[idx], [cres]])
            else:
                A = Ht[np.ix_(idx, idx)]
                rhs = -r[idx]
            try:
                sol = np.linalg.solve(A, rhs)
            except np.linalg.LinAlgError:
                return a, lam, active, taut, it, 'singular KKT matrix', None
            if not np.all(np.isfinite(sol)):
                return a, lam, active, taut, it, 'non-finite Newton step', None
            da = np.zeros(n)
            da[idx] = sol[:m]
            dlam = sol[m] if taut else 0.0
            big = np.max(np.abs(da))
            step = 1.0 if big <= _MAX_STEP_RAD else _MAX_STEP_RAD / big
            # Stop at the first contact bound a free segment would cross.
            new = a + step * da
            hit = free & (np.abs(new) > a_max)
            if hit.any():
                t_hit = (np.sign(da[hit]) * a_max - a[hit]) / da[hit]
                j = np.flatnonzero(hit)[int(np.argmin(t_hit))]
                step = max(0.0, min(step, float(np.min(t_hit))))
                a = a + step * da
                a[j] = math.copysign(a_max, da[j])
                active[j] = int(math.copysign(1, da[j]))
                lam += step * dlam
                continue
            a = new
            lam += step * dlam
        else:
            return a, lam, active, taut, it, f'no convergence in {max_iter} Newton steps', None
        # Converged on this working set: check the multipliers' signs.
        grad, H, L, Lp, Lpp = prob.evaluate(a, tau)
        lam_eff = lam if taut else 0.0
        r = grad + lam_eff * Lp
        changed = False
        if taut and lam < -STATIONARITY_TOL_RAD * float(np.min(prob.k2)):
            taut, lam, changed = False, 0.0, True          # the cable would push: slack
        elif not taut and L - prob.target > CONSTRAINT_TOL_MM:
            taut, lam, changed = True, 0.0, True
        if not changed:
            # Held segment i (a_i = sigma a_c) needs -sigma r_i >= 0: it presses the rib.
            push = -active * r / prob.k2
            bad = (active != 0) & (push < -STATIONARITY_TOL_RAD)
            if bad.any():
                j = int(np.argmin(np.where(bad, push, np.inf)))
                active[j] = 0
                changed = True
        if not changed:
            free = active == 0
            mc = _reduced_hessian_min_eig(H + lam_eff * np.diag(Lpp), free, Lp, taut)
            stat = float(np.max(np.abs(r[free]) / prob.k2[free], initial=0.0))
            cres = L - prob.target
            return a, lam, active, taut, it, 'ok', (cres, stat, mc, L)
    return a, lam, active, taut, it, 'active set did not settle', None


def solve_loaded(skeleton: Skeleton, threading, length_mm: float, loads: Loads,
                 max_iter: int = MAX_ITER) -> LoadedResult:
    """Shape of a module under its weight and a point load at a cable length.

    Parameters
    ----------
    skeleton : Skeleton
    threading : sequence of str or float
        One hole per rib (names or offsets in mm), rib 0 first.
    length_mm : float
        Cable length between the holes of rib 0 and the last rib (mm), > 0. At or above
        the straight length the cable is slack unless the loads stretch the path.
    loads : Loads
        Gravity, bending stiffness and point load. With no in-plane force the answer is
        exactly :func:`softsnap_model.forward.solve_forward`'s.
    max_iter : int
        Newton iterations allowed per load step.

    Returns
    -------
    LoadedResult
        ``converged`` False (with a message) when the contract cannot be met: the load
        passes a fold (the module would snap), or Newton stalls.

    Raises
    ------
    InfeasibleLengthError
        Length below the threading's reachable range (every segment at contact).
    ValueError
        Bad threading, length or loads (message quotes the value and allowed range).

    Examples
    --------
    >>> sk = Skeleton()
    >>> t = 'R1 R1 R1 R1 R1 R1 R1 R1 R2 R2 R3 R3'.split()
    >>> res = solve_loaded(sk, t, 170.0, Loads(gravity_mps2=(0.0, -9.81, 0.0)))
    >>> res.converged, bool(res.angles[0] < solve_forward(sk, t, 170.0).angles[0])
    (True, True)
    """
    if not isinstance(loads, Loads):
        raise ValueError(f'loads must be a Loads, got {type(loads).__name__}')
    if not isinstance(max_iter, numbers.Integral) or max_iter < 1:
        raise ValueError(f'max_iter must be an integer >= 1, got {max_iter!r}')
    d = skeleton.threading_mm(threading)
    forces = loads.rib_forces_n(skeleton.n_ribs)      # validates load_rib and masses
    base = solve_forward(skeleton, d, length_mm)      # validates the length; may raise
    K = loads.bending_stiffness_nmm
    if loads.is_zero:
        return _from_forward(skeleton, d, base, K)
    prob = _Problem(skeleton, d, forces, K, float(length_mm))
    a = np.array(base.angles, dtype=float)
    taut = not base.slack
    lam = base.tension * K if taut else 0.0
    active = np.where(base.at_contact, np.sign(a), 0).astype(int)
    tau, step, iters, steps = 0.0, 1.0, 0, 0
    info, message = None, ''
    while tau < 1.0:
        if steps >= MAX_LOAD_STEPS:
            message = f'load continuation took more than {MAX_LOAD_STEPS} steps'
            break
        trial = min(1.0, tau + step)
        out = _newton(prob, a, lam, active, taut, trial, max_iter)
        iters += out[4]
        ok = out[5] == 'ok' and out[6][2] > 0.0
        if ok:
            a, lam, active, taut = out[0], out[1], out[2], out[3]
            info, tau = out[6], trial
            steps += 1
            step = min(1.0 - tau, 2.0 * step) if tau < 1.0 else step
        else:
            step *= 0.5
            if step < _MIN_LOAD_STEP:
                why = out[5] if out[5] != 'ok' else 'the equilibrium stops being a minimum'
                message = (f'no stable equilibrium on the branch followed from the unloaded '
                           f'shape beyond {tau:.4g} of the load ({why}): the load passes a '
                           f'fold or buckling point (the module would snap or fall over)')
                break
    converged = tau >= 1.0 and info is not None
    if info is None:
        grad, H, L, Lp, Lpp = prob.evaluate(a, tau)
        free = active == 0
        r = grad + (lam if taut else 0.0) * Lp
        info = (L - prob.target, float(np.max(np.abs(r[free]) / prob.k2[free], initial=0.0)),
                _reduced_hessian_min_eig(H, free, Lp, taut), L)
    cres, stat, mc, L = info
    if converged:
        message = 'ok'
    centers = rib_centers(a, skeleton.spacing_mm)
    energy = K * float(skeleton.stiffness_array @ (a * a)) - float(np.sum(forces * centers))
    return LoadedResult(
        angles=a, rib_centers=centers, cable_path=cable_path(a, d, skeleton.spacing_mm),
        tension_n=float(lam) if taut else 0.0, slack=not taut, at_contact=active != 0,
        energy_nmm=energy, cable_length_mm=float(L), converged=bool(converged),
        constraint_residual_mm=float(abs(cres) if taut else max(cres, 0.0)),
        stationarity_residual_rad=float(stat), min_curvature=float(mc),
        is_minimum=bool(mc > 0.0), iterations=int(iters), load_steps=int(steps),
        message=message)


def _from_forward(skeleton, d, base, K) -> LoadedResult:
    """The unloaded answer, unchanged, in the loaded result's units."""
    a = np.array(base.angles, dtype=float)
    prob = _Problem(skeleton, d, np.zeros((skeleton.n_ribs, 2)), K, base.cable_length_mm)
    _, H, L, Lp, Lpp = prob.evaluate(a, 0.0)
    lam = float(base.tension) * K
    at_contact = np.array(base.at_contact, dtype=bool)
    mc = _reduced_hessian_min_eig(H + lam * np.diag(Lpp), ~at_contact, Lp, not base.slack)
    return LoadedResult(
        angles=a, rib_centers=np.array(base.rib_centers), cable_path=np.array(base.cable_path),
        tension_n=lam, slack=bool(base.slack), at_contact=at_contact,
        energy_nmm=K * float(base.energy), cable_length_mm=L, converged=bool(base.converged),
        constraint_residual_mm=float(base.constraint_residual),
        stationarity_residual_rad=float(base.stationarity_residual),
        min_curvature=mc, is_minimum=bool(base.is_minimum), iterations=int(base.iterations),
        load_steps=0, message='no in-plane load: the unloaded solution')
