"""The model node's design services and action: forward shapes and inverse designs.

A mixin of :class:`~softsnap_model.model_node.ModelNode`: ``~/forward_shape``,
``~/inverse_design`` and the ``~/design_threading`` action; designs run on
:class:`DesignWorker` threads so that predictions go on meanwhile.
"""
from __future__ import annotations

import math
import queue
import threading
import time

import numpy as np
from rclpy.action import CancelResponse, GoalResponse
from rclpy.task import Future

from softsnap_ros.units import MM_PER_M
from .shape_stream import points_m
from softsnap_interfaces.msg import Design
from softsnap_interfaces.action import DesignThreading
from softsnap_interfaces.srv import InverseDesign

from .forward import solve_forward
from .friction import solve_friction
from .inverse import DesignCancelled, DesignTimedOut, design_threading
from .loads import Loads, solve_loaded

#: Period of DesignThreading feedback while a goal runs (s).
FEEDBACK_PERIOD_S = 0.1


class DesignWorker:
    """One daemon thread running inverse designs in arrival order.

    A daemon (unlike a ThreadPoolExecutor's worker, which the interpreter joins at exit)
    so that a design can never hold the process up after SIGINT.
    """

    def __init__(self, name: str):
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job) -> None:
        self._jobs.put(job)

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            job()  # jobs catch their own exceptions (see ModelNode._design_job)

    def stop(self, timeout: float) -> bool:
        """Ask the thread to end after its current job; True if it ended within timeout (s)."""
        self._jobs.put(None)
        self._thread.join(timeout)
        return not self._thread.is_alive()


class DesignServices:
    """ForwardShape, InverseDesign and DesignThreading: messages (m) to core calls (mm)."""

    # ------------------------------------------------------------------ services
    def _threading_mm(self, holes, threading_m):
        """Threading from hole names or offsets (m) -> offsets in mm (ValueError if bad)."""
        if len(holes) and len(threading_m):
            raise ValueError('give the threading as hole names or as offsets, not both')
        if len(holes):
            return self.skeleton.threading_mm(list(holes))
        offsets = np.asarray(threading_m, dtype=float) * MM_PER_M
        if not np.all(np.isfinite(offsets)):
            raise ValueError(f'threading offsets must be finite, got {list(threading_m)}')
        return self.skeleton.threading_mm(offsets)

    def forward_shape_callback(self, request, response):
        self.service_calls += 1
        try:
            threading = self._threading_mm(request.holes, request.threading)
            initial = np.asarray(request.initial_angles, dtype=float) if len(request.initial_angles) else None
            loads = self._request_loads(request)
            friction = self._request_friction(request, loads)
            start = time.perf_counter()
            if friction is not None:
                result = solve_friction(self.skeleton, threading, request.cable_length * MM_PER_M,
                                        friction=friction[0], direction=friction[1])
            elif loads.is_zero:
                result = solve_forward(self.skeleton, threading, request.cable_length * MM_PER_M,
                                       initial=initial)
            else:
                result = solve_loaded(self.skeleton, threading,
                                      request.cable_length * MM_PER_M, loads)
            response.solve_time = time.perf_counter() - start
        except (ValueError, TypeError) as error:
            self.service_failures += 1
            response.success = False
            response.message = str(error)
            return response
        except Exception as error:  # a solver bug must not take the node down
            self.service_failures += 1
            self.get_logger().error(f'forward_shape internal error: {error!r}')
            response.success = False
            response.message = f'internal error: {error!r}'
            return response
        response.success = bool(result.converged)
        response.message = getattr(result, 'message', '') or ('converged' if result.converged
                                                             else 'did not converge')
        if not result.converged:
            self.service_failures += 1
        response.angles = np.asarray(result.angles, dtype=float).tolist()
        response.rib_centers = points_m(result.rib_centers)
        response.cable_path = points_m(result.cable_path)
        k_nmm = loads.bending_stiffness_nmm
        n_segments = len(response.angles)
        response.tip_tension_ratio = 1.0
        if friction is not None:
            # The winch's tension is the one the motor feels; per-segment tensions decay
            # (pull) or grow (release) towards the tip.
            response.energy = float(np.sum(self.skeleton.stiffness_array * result.angles ** 2))
            response.tension = float(result.winch_tension) * MM_PER_M
            response.residual = max(float(result.constraint_residual) / MM_PER_M,
                                    float(result.stationarity_residual))
            response.segment_tensions = (np.asarray(result.segment_tensions, dtype=float)
                                         * MM_PER_M).tolist()
            response.wrap_angles = np.asarray(result.wrap_angles, dtype=float).tolist()
            response.tip_tension_ratio = float(result.tip_tension_ratio)
        elif loads.is_zero:
            response.energy = float(result.energy)
            response.tension = float(result.tension) * MM_PER_M
            response.residual = float(result.residual)
            response.segment_tensions = [response.tension] * n_segments
        else:
            # Unit-stiffness fields stay comparable with the unloaded solve's.
            response.energy = float(np.sum(self.skeleton.stiffness_array * result.angles ** 2))
            response.tension = float(result.tension_n) / k_nmm * MM_PER_M
            response.residual = max(float(result.constraint_residual_mm) / MM_PER_M,
                                    float(result.stationarity_residual_rad))
            response.segment_tensions = [response.tension] * n_segments
        response.cable_tension = float(response.tension) / MM_PER_M * k_nmm
        response.converged = bool(result.converged)
        response.iterations = int(result.iterations)
        return response

    @staticmethod
    def _request_friction(request, loads: Loads):
        """(friction coefficient, direction) of a ForwardShape request, or None without
        friction (ValueError if bad or combined with a load)."""
        mu = float(request.friction_coefficient)
        direction = request.direction or 'pull'
        if not (math.isfinite(mu) and 0.0 <= mu <= 2.0):
            raise ValueError(f'friction_coefficient must be in [0, 2], got {mu!r}')
        if direction not in ('pull', 'release'):
            raise ValueError(f"direction must be 'pull' or 'release' (or empty), got {direction!r}")
        if mu == 0.0:
            return None
        if not loads.is_zero:
            raise ValueError('friction_coefficient > 0 cannot be combined with gravity or a load '
                             '(no solver couples them yet): give one or the other')
        return mu, direction

    def _request_loads(self, request) -> Loads:
        """Loads of a ForwardShape request (SI) in the core's units (ValueError if bad)."""
        k_si = float(request.bending_stiffness)
        if k_si == 0.0:
            k_si = float(self.get_parameter('bending_stiffness').value)
        rib = int(request.load_rib)
        if not (math.isfinite(k_si) and k_si > 0.0):
            raise ValueError(f'bending_stiffness must be finite and > 0 N m/rad^2 (0: the '
                             f'node parameter), got {request.bending_stiffness!r}')
        if rib > self.skeleton.n_ribs - 1 or rib < -1:
            raise ValueError(f'load_rib must be 1..{self.skeleton.n_ribs - 1}, or -1 or 0 '
                             f'for the tip; got {rib}')
        g, f = request.gravity, request.load
        return Loads(gravity_mps2=(g.x, g.y, g.z), bending_stiffness_nmm=k_si * MM_PER_M,
                     load_n=(f.x, f.y, f.z), load_rib=-1 if rib == 0 else rib)

    # ------------------------------------------------------------------ inverse design
    def _design_kwargs(self, request) -> dict:
        """Validate an InverseDesign request or DesignThreading goal (same fields) and
        convert it to design_threading arguments (mm); ValueError quoting the bad value."""
        cap = self.get_parameter('max_alternatives').value
        if request.alternatives > cap:
            raise ValueError(f'alternatives {request.alternatives} is above max_alternatives '
                             f'{cap}: ask for at most {cap} (memory and time grow about '
                             'linearly with the alternatives, see docs/inverse.md)')
        has_angles, has_points = len(request.target_angles) > 0, len(request.target_points) > 0
        if has_angles == has_points:
            raise ValueError('give exactly one of target_angles and target_points')
        # 0 means "no bound"; anything else must be a finite, non-negative length.
        bounds = {'min_cable_length': request.min_cable_length,
                  'max_cable_length': request.max_cable_length}
        for name, value in bounds.items():
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f'{name} must be a finite length >= 0 m (0 for no bound), '
                                 f'got {value!r} m')
        low, high = request.min_cable_length, request.max_cable_length
        if low > 0.0 and high > 0.0 and low > high:
            raise ValueError(f'min_cable_length {low!r} m is above max_cable_length {high!r} m')
        kwargs = {'k': int(request.alternatives)}
        if request.allowed_holes:
            kwargs['allowed_holes'] = list(request.allowed_holes)
        if request.forbidden_holes:
            kwargs['forbidden_holes'] = list(request.forbidden_holes)
        if request.fixed_holes:
            kwargs['fixed_holes'] = [h or None for h in request.fixed_holes]
        if low > 0.0 or high > 0.0:
            kwargs['cable_length_range'] = (low * MM_PER_M,
                                            (high if high > 0.0 else math.inf) * MM_PER_M)
        # Tolerances in m on the interface, mm in the core (which checks the range).
        kwargs['hole_tolerance_mm'] = float(request.hole_tolerance) * MM_PER_M
        kwargs['length_tolerance_mm'] = float(request.length_tolerance) * MM_PER_M
        if has_angles:
            kwargs['target_angles'] = list(request.target_angles)
        else:
            kwargs['target_points'] = [(p.x * MM_PER_M, p.y * MM_PER_M)
                                       for p in request.target_points]
        return kwargs

    def _design_job(self, kwargs, arrived, timeout, should_stop, done: Future, progress=None):
        """A worker's job: run one design, never raise, fill ``done`` with
        (outcome, DesignResult or reason) and wake the executor.

        The design must end by ``arrived + timeout`` (monotonic s), waiting included.
        outcome is 'succeeded', 'refused', 'cancelled', 'timed out' or 'failed'."""
        def job():
            try:
                remaining = arrived + timeout - time.monotonic()
                if remaining <= 0.0:
                    answer = ('timed out', f'design_timeout {timeout:g} s passed while the '
                                           'request waited behind another design')
                else:
                    answer = ('succeeded', design_threading(
                        self.skeleton, should_stop=should_stop, time_limit_s=remaining,
                        progress=progress, **kwargs))
            except DesignCancelled as error:
                answer = ('cancelled', str(error))
            except DesignTimedOut as error:
                answer = ('timed out', f'design_timeout {timeout:g} s exceeded: {error}')
            except (ValueError, TypeError) as error:
                answer = ('refused', str(error))
            except Exception as error:  # a solver bug must not kill the worker thread
                answer = ('failed', f'internal error: {error!r}')
            done.set_result(answer)
            try:
                self._design_done.trigger()
            except Exception:  # the node was destroyed meanwhile (shutdown): nobody waits
                pass
        return job

    def _fill_design(self, outcome, answer, out):
        """Fill an InverseDesign.Response or DesignThreading.Result (same fields)."""
        out.success = outcome == 'succeeded'
        if not out.success:
            out.message = f'{outcome}: {answer}'
            return out
        out.message = answer.message or 'ok'
        out.best = self._design_msg(answer)
        out.alternatives = [self._design_msg(alt) for alt in answer.alternatives]
        out.fit_error = float(answer.fit_error) / MM_PER_M
        return out

    async def inverse_design_callback(self, request, response):
        self.service_calls += 1
        arrived = time.monotonic()
        try:
            kwargs = self._design_kwargs(request)
        except (ValueError, TypeError) as error:
            outcome, answer = 'refused', str(error)
        else:
            done = Future()
            self._service_worker.submit(self._design_job(
                kwargs, arrived, self.get_parameter('design_timeout').value,
                self._stopping.is_set, done))
            outcome, answer = await done
        response = self._fill_design(outcome, answer, InverseDesign.Response())
        response.solve_time = time.monotonic() - arrived
        if not response.success:
            self.service_failures += 1
            self.get_logger().warning(f'inverse_design {response.message}')
        return response

    def design_goal_callback(self, goal_request) -> GoalResponse:
        # One goal at a time: a second would only compete for the CPU with the first.
        # Bad goals are accepted and then aborted with the reason (a rejection has none).
        if self._stopping.is_set():
            return GoalResponse.REJECT
        if self._active_goal is not None:
            self.get_logger().warning(
                'design_threading goal rejected: busy with a goal accepted '
                f'{time.monotonic() - self._active_goal[1]:.1f} s ago (one goal at a time; '
                'cancel it, wait, or call ~/inverse_design)')
            return GoalResponse.REJECT
        self._active_goal = (None, time.monotonic())  # reserved until execute runs
        return GoalResponse.ACCEPT

    def design_cancel_callback(self, goal_handle) -> CancelResponse:
        # The design polls the goal's cancel flag between steps of the search.
        return CancelResponse.ACCEPT

    async def design_execute_callback(self, goal_handle):
        accepted = self._active_goal[1] if self._active_goal else time.monotonic()
        self._active_goal = (goal_handle, accepted)
        self.service_calls += 1
        # (fraction, stage): replaced whole by the worker, read by the feedback timer.
        progress = [(0.0, 'queued')]

        def report(fraction, stage):
            progress[0] = (fraction, stage)

        def feedback_callback():
            fraction, stage = progress[0]
            goal_handle.publish_feedback(DesignThreading.Feedback(
                fraction=float(fraction), stage=stage, elapsed=time.monotonic() - accepted))

        feedback_timer = None
        try:
            try:
                kwargs = self._design_kwargs(goal_handle.request)
            except (ValueError, TypeError) as error:
                outcome, answer = 'refused', str(error)
            else:
                done = Future()
                feedback_timer = self.create_timer(FEEDBACK_PERIOD_S, feedback_callback,
                                                   callback_group=self._design_group)
                self._action_worker.submit(self._design_job(
                    kwargs, accepted, self.get_parameter('design_timeout').value,
                    lambda: self._stopping.is_set() or goal_handle.is_cancel_requested,
                    done, report))
                outcome, answer = await done
                if outcome == 'succeeded':
                    feedback_callback()  # the final 'done' at fraction 1
            result = self._fill_design(outcome, answer, DesignThreading.Result())
            result.solve_time = time.monotonic() - accepted
            if outcome == 'succeeded':
                goal_handle.succeed()
            elif outcome == 'cancelled' and goal_handle.is_cancel_requested:
                goal_handle.canceled()
                self.get_logger().info(f'design_threading {result.message}')
            else:  # refused, timed out, failed, or stopped by shutdown
                goal_handle.abort()
                self.get_logger().warning(f'design_threading aborted: {result.message}')
            if not result.success:
                self.service_failures += 1
            return result
        finally:
            if feedback_timer is not None:
                self.destroy_timer(feedback_timer)
            self._active_goal = None

    @staticmethod
    def _design_msg(result) -> Design:
        sens = getattr(result, 'sensitivity', None)
        return Design(
            holes=list(result.holes),
            threading=(np.asarray(result.threading, dtype=float) / MM_PER_M).tolist(),
            cable_length=float(result.cable_length) / MM_PER_M,
            angles=np.asarray(result.angles, dtype=float).tolist(),
            rib_centers=points_m(result.rib_centers),
            error=float(result.error),
            position_error=float(result.position_error) / MM_PER_M,
            tolerance_median_error=sens.median_error if sens is not None else math.nan,
            tolerance_p90_error=sens.p90_error if sens is not None else math.nan)
