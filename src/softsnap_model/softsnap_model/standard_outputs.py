"""The model node's standard outputs: markers for RViz and its diagnostics.

A mixin of :class:`~softsnap_model.model_node.ModelNode`; the messages are built by
:mod:`.standard_messages`.
"""
from __future__ import annotations


from diagnostic_msgs.msg import DiagnosticArray
from visualization_msgs.msg import MarkerArray

from softsnap_interfaces.msg import ModelDiagnostics, RobotShape

from .predictor import SOURCES
from . import standard_messages as standard


class StandardOutputs:
    """model/markers, model/diagnostics and /diagnostics, built only while subscribed."""

    # ------------------------------------------------------------------ standard outputs
    def simulated_shape_callback(self, msg: RobotShape) -> None:
        self._simulated = msg  # drawn (and checked) at the next marker tick, if watched

    def marker_callback(self) -> None:
        """Publish model/markers if someone subscribes (called by the prediction thread when
        due)."""
        if self._subscribers(self.marker_publisher) == 0:
            return  # nobody watches: build nothing
        try:
            markers = self._model_markers() + self._simulated_markers()
        except Exception as error:  # never let a marker bug stop the node
            self.get_logger().error(f'markers failed: {error!r}', throttle_duration_sec=1.0)
            return
        self.marker_publisher.publish(MarkerArray(markers=markers))
        self.marker_arrays_published += 1

    def _model_markers(self) -> list:
        """Markers of every solved shape; a (module, source)'s markers are updated only
        when its shape (a new object for every solve) or its base pose changed, in place
        (the previous array was serialised when published)."""
        markers = []
        for source in SOURCES:
            for index, (module, shape, pose) in enumerate(zip(
                    self.scene.modules, self.predictor.shapes(source),
                    self.predictor.base_poses(source))):
                if shape is None:
                    continue
                cached = self._marker_cache.get((module.name, source))
                if cached is None or cached[0] is not shape or cached[1] != pose:
                    cached = (shape, pose, standard.prediction_markers(
                        shape, module_index=index, threading_mm=module.threading_mm,
                        base_pose_m=pose, frame_id=self.scene.name,
                        spacing_mm=self.skeleton.spacing_mm,
                        rib_length_mm=self.skeleton.rib_length_mm,
                        reuse=cached[2] if cached is not None else ()))
                    self._marker_cache[(module.name, source)] = cached
                markers += cached[2]
        return markers

    def _simulated_markers(self) -> list:
        msg = self._simulated
        if msg is None:
            return []
        cached = self._marker_cache.get(('', 'simulated'))
        if cached is not None and cached[0] is msg:
            return cached[1]
        markers, problems = standard.robot_shape_markers(
            msg, default_frame_id=self.scene.name, module_names=self.scene.module_names,
            threadings_mm={m.name: m.threading_mm for m in self.scene.modules},
            spacing_mm=self.skeleton.spacing_mm, rib_length_mm=self.skeleton.rib_length_mm)
        for problem in problems:
            self.get_logger().warning(f'simulated {problem}', throttle_duration_sec=5.0)
        self._marker_cache[('', 'simulated')] = (msg, markers)
        return markers

    def diagnostics_callback(self) -> None:
        c = self.predictor.counters
        solves_before, time_before = self._solve_time_reported
        n = c.solves - solves_before
        msg = ModelDiagnostics(
            solves=c.solves, skipped_unchanged=c.skipped_unchanged,
            skipped_duplicate=c.skipped_duplicate, skipped_rib_points=c.skipped_rib_points,
            refused=c.refused, service_calls=self.service_calls,
            service_failures=self.service_failures,
            mean_solve_time=(c.solve_time_s - time_before) / n if n else 0.0)
        health = standard.ModelHealth(
            solves=c.solves, skipped_unchanged=c.skipped_unchanged,
            skipped_duplicate=c.skipped_duplicate, skipped_rib_points=c.skipped_rib_points,
            refused=c.refused, service_calls=self.service_calls,
            service_failures=self.service_failures, mean_solve_time_s=msg.mean_solve_time,
            marker_arrays_published=self.marker_arrays_published,
            joint_states_published=self.joint_states_published)
        diagnostics = DiagnosticArray(status=[standard.model_status(
            f'softsnap/{self.scene.name}/model', health, self._health_reported,
            1.0 / self.get_parameter('rate').value)])
        diagnostics.header.stamp = self.get_clock().now().to_msg()
        self._health_reported = health
        self.ros_diagnostics_publisher.publish(diagnostics)
        msg.modules = [m.name for m in self.scene.modules]
        taken = dict(zip(self._length_keys, self.lengths_taken))
        msg.commanded_lengths = [taken[(m, 'commanded')] for m in msg.modules]
        msg.measured_lengths = [taken[(m, 'predicted')] for m in msg.modules]
        msg.header.stamp = self.get_clock().now().to_msg()
        self._solve_time_reported = (c.solves, c.solve_time_s)
        self.diagnostics_publisher.publish(msg)
