"""Robot scenes: which SoftSnap modules a robot has, how each is threaded and where it sits.

A scene file (YAML, format described in docs/scenes.md) names the robot, states its
connector geometry in millimetres, lists its modules (threading, driver address, base
pose on the connector) and the gaits the robot can run. `load_scene` validates a file
and returns a frozen `Scene`; every validation failure is a `SceneError` naming the file,
the key path (``modules[2].threading``) and what was expected.

Frames. Each module has its own frame: rib 0 at the origin, the straight spine along +x,
bending in the module's x-y plane (a positive bending angle turns the spine
counter-clockwise about +z, toward +y). A module's base pose maps its module frame into
the robot frame (metres, unit quaternion x, y, z, w). For chains (the snake) a module may
name a ``parent``: its base is then attached to the parent's tip rib, and
`compose_base_pose` places it from the parent's current tip pose; its `base_position_m`
and `base_orientation_xyzw` are the pose with every module straight.

Pure Python + PyYAML: no ROS import, so the model node, the gait node, the rerun logger
and offline tools can all read scenes. Scene files live in the softsnap_gaits package
(share/softsnap_gaits/scenes); `find_scene` looks them up at run time only.

Examples
--------
>>> scene = load_scene('brittle_star')
>>> [m.name for m in scene.modules]
['yellow', 'blue', 'green', 'red', 'orange']
>>> scene.modules[0].port
8101
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import yaml

__all__ = [
    'Scene', 'SceneModule', 'SceneError', 'load_scene', 'find_scene', 'list_scenes',
    'compose_base_pose', 'straight_tip_pose', 'quaternion_to_matrix', 'SCENE_FORMAT', 'DEFAULT_HOST',
    'DEFAULT_COUNTS_PER_MM', 'DEFAULT_WINCH_SPEED_MM_S', 'PAPER_MAX_CONTRACTION_MM',
    'SCENE_PATH_ENV',
]

#: Scene file format version this loader understands (the file's ``format`` key).
SCENE_FORMAT = 1
#: Driver host when a scene gives none: a simulated module on this machine.
DEFAULT_HOST = '127.0.0.1'
#: Encoder counts per millimetre of cable when a scene gives none. Our estimate, to be
#: replaced by a calibration per module: GA12-N20 with a 7-pulse-per-revolution
#: quadrature encoder (28 counts per motor turn), 1:100 gearbox (2800 counts per winch
#: turn), winch drum 10 mm in diameter (31.4 mm of cable per turn).
DEFAULT_COUNTS_PER_MM = 2800.0 / (math.pi * 10.0)
#: Cable speed of a winch (mm/s) when a scene gives none: the speed the driver's motor
#: model (softsnap_driver.firmware.MotorModel, FACTS.md) gives at the driver's default PWM.
#: GA12-N20 1:100: 300 rpm at the output shaft at 6 V without load (the firmware boosts the
#: motor to 6 V while it is more than 60 counts from its target); the cable load takes 25 %
#: of the stall torque (speed x 0.75); the driver sends PWM 200 of 255; the 10 mm drum
#: winds pi * 10 mm per turn: 300 / 60 * 0.75 * 200 / 255 * pi * 10 = 92.4 mm/s.
#: Not imported from the driver (softsnap_model does not depend on it);
#: test/softsnap_model/test_scenes.py checks it against the motor model.
DEFAULT_WINCH_SPEED_MM_S = 300.0 / 60.0 * (1.0 - 0.25) * (200.0 / 255.0) * math.pi * 10.0
#: Largest cable contraction shown in the paper (mm); the default per-module limit.
PAPER_MAX_CONTRACTION_MM = 80.0
#: Environment variable: extra directories (os.pathsep-separated) searched for scenes first.
SCENE_PATH_ENV = 'SOFTSNAP_SCENE_PATH'

#: Tolerance on the orthogonality and length of orientation axes given in a file.
AXIS_TOL = 1e-6
#: Tolerances (m, rad) on a chained module's stated base pose against its parent's.
CHAIN_POSE_TOL_M = 5e-4
CHAIN_ANGLE_TOL_RAD = 1e-3
#: Fastest winch a scene may state (mm/s): 10 m/s of cable is far beyond any module motor,
#: so a larger value is a unit mistake (m/s or counts/s).
MAX_WINCH_SPEED_MM_S = 10000.0
#: Largest distance (m) of a module base from the robot origin that we accept: a chain of
#: 4,000 modules (248 mm each) fits; a base farther away is a unit mistake (micrometres).
#: It was 5 m, which capped a straight chain at ~20 modules (issue 37).
MAX_BASE_DISTANCE_M = 1000.0

_SCENE_SUFFIXES = ('.yaml', '.yml')


class SceneError(ValueError):
    """A scene file is missing or invalid; the message names the file, key path and rule."""


@dataclass(frozen=True)
class SceneModule:
    """One module of a robot, as placed in the scene.

    Attributes
    ----------
    name : str
        Unique name within the scene; also the ROS namespace of its topics.
    holes : tuple of str
        Hole names, rib 0 first (one per rib), e.g. ``('R1', 'R2', ...)``.
    threading_mm : tuple of float
        Hole offsets along each rib (mm), rib 0 first, from the scene's skeleton.
    base_position_m : tuple of float
        Position of rib 0 in the robot frame (m), all modules straight.
    base_orientation_xyzw : tuple of float
        Unit quaternion rotating module-frame vectors into the robot frame.
    host, port : str, int
        Driver address of the module (simulated modules: 127.0.0.1 and a distinct port).
    counts_per_mm : float
        Encoder counts per millimetre of cable (a calibrated parameter of the winch).
    straight_length_mm : float
        Cable length inside the straight skeleton (mm), the largest commandable length.
    max_contraction_mm : float
        User limit on the cable contraction (mm); gaits are also held to the solver's
        reachable range.
    winch_speed_mm_s : float
        Cable speed of the module's winch at full drive (mm/s of cable); gaits are held
        to a fraction of it (softsnap_gaits.gaits.WINCH_SPEED_MARGIN).
    color : str
        Display colour (the paper's module colours for the starfish and brittle star).
    parent : str or None
        For chains: the module whose tip rib this module's base is attached to.
    parent_offset_position_m, parent_offset_orientation_xyzw
        Pose of this module's base in the parent's tip-rib frame (only with ``parent``).
    index : int
        Position in `Scene.modules`.
    tag_id : int or None
        ArUco tag id on the module's case (the file's ``markers: {tag_id: N}``), by which
        a camera tells the modules apart (softsnap_vision's marker_tracker); None when
        the scene gives none (the tracker then takes the module's index).
    """

    name: str
    holes: tuple[str, ...]
    threading_mm: tuple[float, ...]
    base_position_m: tuple[float, float, float]
    base_orientation_xyzw: tuple[float, float, float, float]
    host: str
    port: int
    counts_per_mm: float
    straight_length_mm: float
    max_contraction_mm: float = PAPER_MAX_CONTRACTION_MM
    winch_speed_mm_s: float = DEFAULT_WINCH_SPEED_MM_S
    color: str = ''
    parent: str | None = None
    parent_offset_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    parent_offset_orientation_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    index: int = 0
    tag_id: int | None = None

    @property
    def address(self) -> str:
        """``host:port`` of the module's driver."""
        return f'{self.host}:{self.port}'

    @property
    def bending_normal(self) -> tuple[float, float, float]:
        """Robot-frame axis about which the module bends (module +z, normal of its bending plane)."""
        rot = quaternion_to_matrix(self.base_orientation_xyzw)
        return (rot[0][2], rot[1][2], rot[2][2])


@dataclass(frozen=True, eq=False)   # identity equality/hash: the read-only mappings are unhashable
class Scene:
    """A validated robot scene (see the module docstring and docs/scenes.md).

    Attributes
    ----------
    name : str
        Scene name (the file's ``name``; equals the file stem for installed scenes).
    description : str
        One paragraph for users.
    connector : Mapping
        Connector geometry as stated in the file (lengths in ``*_mm`` keys, angles in
        ``*_deg``, plus ``type`` and ``source``), read-only.
    modules : tuple of SceneModule
        Modules in file order.
    gaits : Mapping
        Gait name -> gait spec (read-only mapping, validated by softsnap_gaits.gaits).
    skeleton : softsnap_model.Skeleton
        Skeleton geometry shared by the modules (the authors' module unless the file
        overrides it).
    default_gait : str
        Gait the gait node runs when none is requested.
    path : Path
        File the scene was read from.
    frame : str
        Free-text description of the robot frame.
    """

    name: str
    description: str
    connector: Mapping[str, Any]
    modules: tuple[SceneModule, ...]
    gaits: Mapping[str, Mapping[str, Any]]
    skeleton: Any
    default_gait: str
    path: Path
    frame: str = ''
    _by_name: Mapping[str, SceneModule] = field(default_factory=dict, repr=False, compare=False)

    @property
    def robot(self) -> str:
        """Alias of `name`."""
        return self.name

    @property
    def module_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.modules)

    def module(self, name: str) -> SceneModule:
        """The module called `name`; KeyError naming the known modules otherwise."""
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f'scene {self.name!r} has no module {name!r}; '
                           f'modules are {", ".join(self.module_names)}') from None


# ----------------------------------------------------------------------------- lookup

def _search_dirs() -> list[Path]:
    """Directories searched for scene files, first match wins."""
    dirs = [Path(p) for p in os.environ.get(SCENE_PATH_ENV, '').split(os.pathsep) if p]
    try:  # Installed package share (ament index); a runtime lookup, not a dependency.
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory('softsnap_gaits')) / 'scenes')
    except Exception:  # noqa: BLE001 - ament_index missing or package not installed
        pass
    # Source tree: src/softsnap_model/softsnap_model/scene.py -> src/softsnap_gaits/scenes.
    for base in {Path(__file__).resolve().parents[2], Path(__file__).absolute().parents[2]}:
        dirs.append(base / 'softsnap_gaits' / 'scenes')
    unique: list[Path] = []
    for d in dirs:
        if d not in unique:
            unique.append(d)
    return unique


def find_scene(name: str | os.PathLike) -> Path:
    """Resolve a scene name (``'brittle_star'``) or a file path to an existing file.

    A value that names an existing file (or contains a path separator or a .yaml
    suffix) is taken as a path. A bare name is searched in $SOFTSNAP_SCENE_PATH, then
    the installed share/softsnap_gaits/scenes, then the source tree.
    """
    text = os.fspath(name)
    path = Path(text).expanduser()
    if path.is_file():
        return path
    if os.sep in text or path.suffix in _SCENE_SUFFIXES:
        raise SceneError(f'{text}: scene file not found')
    if not text:
        raise SceneError('empty scene name; known scenes: ' + ', '.join(list_scenes()))
    for directory in _search_dirs():
        for suffix in _SCENE_SUFFIXES:
            candidate = directory / f'{text}{suffix}'
            if candidate.is_file():
                return candidate
    raise SceneError(f'unknown scene {text!r}; known scenes: {", ".join(list_scenes()) or "none"}')


def list_scenes() -> list[str]:
    """Names of all scenes `find_scene` can resolve, sorted."""
    names = set()
    for directory in _search_dirs():
        if directory.is_dir():
            names.update(p.stem for p in directory.iterdir()
                         if p.suffix in _SCENE_SUFFIXES and p.is_file())
    return sorted(names)


# ------------------------------------------------------------------------- rotations

def _matrix_to_quaternion(rot: list[list[float]]) -> tuple[float, float, float, float]:
    """Rotation matrix (rows) -> unit quaternion (x, y, z, w) with w >= 0."""
    m00, m01, m02 = rot[0]
    m10, m11, m12 = rot[1]
    m20, m21, m22 = rot[2]
    trace = m00 + m11 + m22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        w, x, y, z = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        w, x, y, z = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        w, x, y, z = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        w, x, y, z = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    return (_clean(x / n), _clean(y / n), _clean(z / n), _clean(w / n))


def _clean(v: float) -> float:
    """Round away floating-point dust (|v| < 1e-15 -> 0.0) so files round-trip cleanly."""
    return 0.0 if abs(v) < 1e-15 else v


def quaternion_to_matrix(q: tuple[float, float, float, float]) -> list[list[float]]:
    """Unit quaternion (x, y, z, w) -> 3x3 rotation matrix as nested lists (rows)."""
    x, y, z, w = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def _rpy_to_matrix(roll: float, pitch: float, yaw: float) -> list[list[float]]:
    """Fixed-axis roll (x), pitch (y), yaw (z), radians: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def _matmul(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _apply(rot: list[list[float]], v) -> tuple[float, float, float]:
    return tuple(sum(rot[i][k] * v[k] for k in range(3)) for i in range(3))


def compose_base_pose(parent_tip_position_m, parent_tip_orientation_xyzw,
                      module: SceneModule):
    """Robot-frame base pose of a chained module from its parent's current tip-rib pose.

    Parameters
    ----------
    parent_tip_position_m : sequence of 3 float
        Parent's tip rib (rib 11 for the authors' module) in the robot frame (m).
    parent_tip_orientation_xyzw : sequence of 4 float
        Orientation of the parent's tip-rib frame (x along the spine at the tip).
    module : SceneModule
        The child; its ``parent_offset_*`` give its base in the parent's tip frame.

    Returns
    -------
    (position_m, orientation_xyzw) : tuple
    """
    rot_tip = quaternion_to_matrix(tuple(parent_tip_orientation_xyzw))
    offset = _apply(rot_tip, module.parent_offset_position_m)
    position = tuple(p + o for p, o in zip(parent_tip_position_m, offset))
    rot = _matmul(rot_tip, quaternion_to_matrix(module.parent_offset_orientation_xyzw))
    return position, _matrix_to_quaternion(rot)


# ------------------------------------------------------------------------ validation

class _Checker:
    """Reads typed values out of the parsed YAML, raising SceneError with the key path."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, expected: str, value: Any = None, *, show_value: bool = True):
        got = f', got {value!r}' if show_value else ''
        raise SceneError(f'{self.path}: {key}: expected {expected}{got}')

    def mapping(self, value, key):
        if not isinstance(value, Mapping):
            self.fail(key, 'a mapping (key: value)', value)
        for k in value:
            if not isinstance(k, str):
                self.fail(key, 'string keys', k)
        return value

    def keys(self, value: Mapping, key: str, required: set[str], optional: set[str]):
        missing = sorted(required - set(value))
        if missing:
            self.fail(key, f'key {missing[0]!r} (required keys: {", ".join(sorted(required))})',
                      show_value=False)
        unknown = sorted(set(value) - required - optional)
        if unknown:
            allowed = ', '.join(sorted(required | optional))
            self.fail(f'{key}.{unknown[0]}' if key else unknown[0],
                      f'one of the known keys ({allowed})', unknown[0])

    def string(self, value, key, *, nonempty=True):
        if not isinstance(value, str) or (nonempty and not value.strip()):
            self.fail(key, 'a non-empty string' if nonempty else 'a string', value)
        return value

    def identifier(self, value, key):
        self.string(value, key)
        if not (value.replace('_', 'a').isalnum() and value.isascii() and not value[0].isdigit()):
            self.fail(key, 'a name of letters, digits and underscores, not starting with a digit'
                      ' (it becomes a ROS namespace)', value)
        return value

    def number(self, value, key, *, low=None, high=None, low_open=False):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(key, 'a finite number', value)
        value = float(value)
        if low is not None and (value < low or (low_open and value == low)):
            self.fail(key, f'a number {">" if low_open else ">="} {low:g}'
                      + (f' and <= {high:g}' if high is not None else ''), value)
        if high is not None and value > high:
            self.fail(key, f'a number <= {high:g}', value)
        return value

    def integer(self, value, key, *, low, high):
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            self.fail(key, f'an integer from {low} to {high}', value)
        return value

    def vector(self, value, key, n, *, unit_name=''):
        if not isinstance(value, (list, tuple)) or len(value) != n:
            count = f'got {len(value)}' if isinstance(value, (list, tuple)) else f'got {value!r}'
            raise SceneError(f'{self.path}: {key}: expected {n} numbers{unit_name}, {count}')
        return tuple(self.number(v, f'{key}[{i}]') for i, v in enumerate(value))


_TOP_REQUIRED = {'format', 'name', 'description', 'connector', 'modules', 'gaits', 'default_gait'}
_TOP_OPTIONAL = {'frame', 'defaults', 'skeleton'}
_DEFAULT_KEYS = {'host', 'counts_per_mm', 'max_contraction_mm', 'winch_speed_mm_s'}
_MODULE_REQUIRED = {'name', 'threading', 'port', 'base'}
_MODULE_OPTIONAL = {'host', 'counts_per_mm', 'max_contraction_mm', 'winch_speed_mm_s', 'color',
                    'parent', 'parent_offset', 'markers'}
#: Keys of a module's ``markers`` (what a camera identifies it by, softsnap_vision).
_MARKER_KEYS = {'tag_id'}
#: Largest ArUco / AprilTag id a scene may give (the biggest dictionaries have 1000 ids).
MAX_TAG_ID = 999
_POSE_ORIENTATIONS = ('axes', 'rpy_deg', 'orientation_xyzw')
_SKELETON_KEYS = {'n_ribs', 'spacing_mm', 'rib_length_mm', 'holes_mm', 'stiffness',
                  'rib_thickness_mm'}


def _orientation(chk: _Checker, pose: Mapping, key: str) -> tuple[float, float, float, float]:
    """Quaternion from exactly one of: axes {x, y}, rpy_deg [r, p, y], orientation_xyzw."""
    given = [k for k in _POSE_ORIENTATIONS if k in pose]
    if len(given) != 1:
        chk.fail(key, 'exactly one orientation: axes {x: [..], y: [..]} (module x = spine, '
                 'module y = direction of positive bending), rpy_deg [roll, pitch, yaw] or '
                 'orientation_xyzw [x, y, z, w]', sorted(given))
    kind = given[0]
    sub = f'{key}.{kind}'
    if kind == 'orientation_xyzw':
        q = chk.vector(pose[kind], sub, 4)
        n = math.sqrt(sum(c * c for c in q))
        if abs(n - 1.0) > 1e-3:
            chk.fail(sub, 'a unit quaternion (norm 1 within 1e-3)', list(q))
        return _matrix_to_quaternion(quaternion_to_matrix(tuple(c / n for c in q)))
    if kind == 'rpy_deg':
        r, p, y = (math.radians(v) for v in chk.vector(pose[kind], sub, 3))
        return _matrix_to_quaternion(_rpy_to_matrix(r, p, y))
    axes = chk.mapping(pose[kind], sub)
    chk.keys(axes, sub, {'x', 'y'}, set())
    x = chk.vector(axes['x'], f'{sub}.x', 3)
    y = chk.vector(axes['y'], f'{sub}.y', 3)
    nx, ny = math.sqrt(sum(c * c for c in x)), math.sqrt(sum(c * c for c in y))
    if nx < 1e-9 or ny < 1e-9:
        chk.fail(sub, 'non-zero axis vectors', {'x': list(x), 'y': list(y)})
    x = tuple(c / nx for c in x)
    y = tuple(c / ny for c in y)
    dot = sum(a * b for a, b in zip(x, y))
    if abs(dot) > AXIS_TOL * 1e3:
        chk.fail(sub, f'perpendicular x and y axes (|cos| <= {AXIS_TOL * 1e3:g})',
                 f'cos = {dot:.6f}')
    z = (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])
    rot = [[x[i], y[i], z[i]] for i in range(3)]
    return _matrix_to_quaternion(rot)


def _pose(chk: _Checker, value, key: str):
    pose = chk.mapping(value, key)
    chk.keys(pose, key, {'position_mm'}, set(_POSE_ORIENTATIONS))
    pos_mm = chk.vector(pose['position_mm'], f'{key}.position_mm', 3, unit_name=' (mm)')
    pos_m = tuple(_clean(round(c / 1000.0, 12)) for c in pos_mm)
    if math.sqrt(sum(c * c for c in pos_m)) > MAX_BASE_DISTANCE_M:
        chk.fail(f'{key}.position_mm', f'a position within {MAX_BASE_DISTANCE_M * 1000:g} mm '
                 'of the robot origin (positions are in millimetres)', list(pos_mm))
    return pos_m, _orientation(chk, pose, key)


def _skeleton_class():
    from softsnap_model.skeleton import Skeleton  # noqa: PLC0415 - lazy: no import cycle
    return Skeleton


def _default_skeleton():
    return _skeleton_class()()


def _make_skeleton(chk: _Checker, value, key: str):
    """The authors' skeleton, or one built from the file's override (Skeleton.from_dict keys)."""
    if value is None:
        return _default_skeleton()
    spec = chk.mapping(value, key)
    chk.keys(spec, key, set(), _SKELETON_KEYS)
    try:
        return _skeleton_class().from_dict(dict(spec))
    except (TypeError, ValueError) as exc:
        raise SceneError(f'{chk.path}: {key}: invalid skeleton ({exc})') from None


def _hole_offsets(skeleton) -> Mapping[str, float]:
    for attr in ('holes_mm', 'hole_offsets_mm', 'holes'):
        holes = getattr(skeleton, attr, None)
        if isinstance(holes, Mapping):
            return holes
    return {}


def _threading(chk: _Checker, value, key: str, skeleton):
    n_ribs = int(getattr(skeleton, 'n_ribs', 12))
    if isinstance(value, str):
        value = value.split()
    if not isinstance(value, (list, tuple)) or not all(isinstance(h, str) for h in value):
        chk.fail(key, f'a list of {n_ribs} hole names (rib 0 first)', value)
    if len(value) != n_ribs:
        raise SceneError(f'{chk.path}: {key}: expected {n_ribs} hole names (one per rib, '
                         f'rib 0 first), got {len(value)}')
    holes = tuple(value)
    known = _hole_offsets(skeleton)
    for i, h in enumerate(holes):
        if known and h not in known:
            chk.fail(f'{key}[{i}]', f'a hole name ({", ".join(known)})', h)
    try:
        offsets = tuple(float(d) for d in skeleton.threading_mm(holes))
        straight = float(skeleton.straight_length_mm(offsets))
    except (KeyError, ValueError, TypeError) as exc:
        raise SceneError(f'{chk.path}: {key}: invalid threading {list(holes)} ({exc})') from None
    return holes, offsets, straight


def straight_tip_pose(module: SceneModule, skeleton):
    """Robot-frame pose of a straight module's tip rib: base pose moved along the spine."""
    n_ribs = int(getattr(skeleton, 'n_ribs', 12))
    spine_m = (n_ribs - 1) * float(getattr(skeleton, 'spacing_mm', 18.0)) / 1000.0
    rot = quaternion_to_matrix(module.base_orientation_xyzw)
    tip = _apply(rot, (spine_m, 0.0, 0.0))
    return (tuple(b + t for b, t in zip(module.base_position_m, tip)),
            module.base_orientation_xyzw)


def _check_chained_pose(chk: _Checker, i: int, module: SceneModule, parent: SceneModule,
                        skeleton) -> None:
    """A chained module's straight base pose must follow from its parent's and the offset."""
    expected_pos, expected_q = compose_base_pose(*straight_tip_pose(parent, skeleton), module)
    err_m = math.dist(expected_pos, module.base_position_m)
    dot = abs(sum(a * b for a, b in zip(expected_q, module.base_orientation_xyzw)))
    err_rad = 2.0 * math.acos(min(1.0, dot))
    if err_m > CHAIN_POSE_TOL_M or err_rad > CHAIN_ANGLE_TOL_RAD:
        chk.fail(f'modules[{i}].base', 'the pose given by the parent '
                 f'{parent.name!r} (straight) and parent_offset: position_mm '
                 f'{[round(c * 1000.0, 3) for c in expected_pos]}, orientation_xyzw '
                 f'{[round(c, 6) for c in expected_q]}',
                 f'{[round(c * 1000.0, 3) for c in module.base_position_m]} mm, '
                 f'{[round(c, 6) for c in module.base_orientation_xyzw]}')


def load_scene(path_or_name: str | os.PathLike) -> Scene:
    """Read and validate a scene file; `path_or_name` is a path or a name for `find_scene`.

    Raises
    ------
    SceneError
        The file is missing, is not YAML, or breaks a rule; the message names the file,
        the key path and what was expected.
    """
    path = find_scene(path_or_name)
    chk = _Checker(path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SceneError(f'{path}: not valid YAML: {exc}') from None
    except OSError as exc:
        raise SceneError(f'{path}: cannot read: {exc}') from None
    chk.mapping(data, '(top level)')
    chk.keys(data, '', _TOP_REQUIRED, _TOP_OPTIONAL)
    if data['format'] != SCENE_FORMAT:
        chk.fail('format', f'{SCENE_FORMAT} (the scene format this loader reads)', data['format'])
    name = chk.identifier(data['name'], 'name')
    description = chk.string(data['description'], 'description')
    frame = chk.string(data.get('frame', ''), 'frame', nonempty=False)

    connector = chk.mapping(data['connector'], 'connector')
    chk.string(connector.get('type'), 'connector.type')
    chk.string(connector.get('source'), 'connector.source')
    for k, v in connector.items():
        if k in ('type', 'source', 'notes'):
            chk.string(v, f'connector.{k}')
        elif k.endswith('_mm'):
            chk.number(v, f'connector.{k}', low=0.0, low_open=True, high=5000.0)
        elif k.endswith('_deg'):
            chk.number(v, f'connector.{k}', low=-360.0, high=360.0)
        elif k.endswith('_count'):
            chk.integer(v, f'connector.{k}', low=1, high=100)
        else:
            chk.fail(f'connector.{k}', 'type, source, notes or a dimension whose key states its '
                     'unit (*_mm, *_deg, *_count)', k)

    defaults = chk.mapping(data.get('defaults') or {}, 'defaults')
    chk.keys(defaults, 'defaults', set(), _DEFAULT_KEYS)
    default_host = chk.string(defaults.get('host', DEFAULT_HOST), 'defaults.host')
    default_cpm = chk.number(defaults.get('counts_per_mm', DEFAULT_COUNTS_PER_MM),
                             'defaults.counts_per_mm', low=0.0, low_open=True, high=1e6)
    default_max = chk.number(defaults.get('max_contraction_mm', PAPER_MAX_CONTRACTION_MM),
                             'defaults.max_contraction_mm', low=0.0, low_open=True, high=1000.0)
    default_speed = chk.number(defaults.get('winch_speed_mm_s', DEFAULT_WINCH_SPEED_MM_S),
                               'defaults.winch_speed_mm_s', low=0.0, low_open=True,
                               high=MAX_WINCH_SPEED_MM_S)

    skeleton = _make_skeleton(chk, data.get('skeleton'), 'skeleton')

    raw_modules = data['modules']
    if not isinstance(raw_modules, list) or not raw_modules:
        chk.fail('modules', 'a non-empty list of modules', raw_modules)
    modules: list[SceneModule] = []
    seen_names: dict[str, int] = {}
    seen_addresses: dict[tuple[str, int], int] = {}
    seen_tags: dict[int, int] = {}
    for i, raw in enumerate(raw_modules):
        key = f'modules[{i}]'
        chk.mapping(raw, key)
        chk.keys(raw, key, _MODULE_REQUIRED, _MODULE_OPTIONAL)
        mname = chk.identifier(raw['name'], f'{key}.name')
        if mname in seen_names:
            chk.fail(f'{key}.name', f'a unique module name (modules[{seen_names[mname]}] '
                     'has the same)', mname)
        seen_names[mname] = i
        holes, offsets, straight = _threading(chk, raw['threading'], f'{key}.threading', skeleton)
        host = chk.string(raw.get('host', default_host), f'{key}.host')
        port = chk.integer(raw['port'], f'{key}.port', low=1, high=65535)
        if (host, port) in seen_addresses:
            chk.fail(f'{key}.port', f'a driver address not used by another module '
                     f'(modules[{seen_addresses[(host, port)]}] uses {host}:{port})', port)
        seen_addresses[(host, port)] = i
        cpm = chk.number(raw.get('counts_per_mm', default_cpm), f'{key}.counts_per_mm',
                         low=0.0, low_open=True, high=1e6)
        max_c = chk.number(raw.get('max_contraction_mm', default_max),
                           f'{key}.max_contraction_mm', low=0.0, low_open=True, high=straight)
        speed = chk.number(raw.get('winch_speed_mm_s', default_speed), f'{key}.winch_speed_mm_s',
                           low=0.0, low_open=True, high=MAX_WINCH_SPEED_MM_S)
        color = chk.string(raw.get('color', ''), f'{key}.color', nonempty=False)
        position, orientation = _pose(chk, raw['base'], f'{key}.base')
        parent = raw.get('parent')
        offset_pos, offset_q = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
        if parent is not None:
            chk.identifier(parent, f'{key}.parent')
            if 'parent_offset' not in raw:
                chk.fail(key, 'parent_offset (base pose in the parent tip-rib frame) with parent',
                         show_value=False)
            offset_pos, offset_q = _pose(chk, raw['parent_offset'], f'{key}.parent_offset')
        elif 'parent_offset' in raw:
            chk.fail(f'{key}.parent_offset', 'parent_offset only together with parent',
                     show_value=False)
        tag_id = None
        if 'markers' in raw:
            markers = chk.mapping(raw['markers'], f'{key}.markers')
            chk.keys(markers, f'{key}.markers', set(), _MARKER_KEYS)
            if 'tag_id' in markers:
                tag_id = chk.integer(markers['tag_id'], f'{key}.markers.tag_id', low=0,
                                     high=MAX_TAG_ID)
                if tag_id in seen_tags:
                    chk.fail(f'{key}.markers.tag_id', f'a tag id no other module has '
                             f'(modules[{seen_tags[tag_id]}] has {tag_id})', tag_id)
                seen_tags[tag_id] = i
        modules.append(SceneModule(
            name=mname, holes=holes, threading_mm=offsets, base_position_m=position,
            base_orientation_xyzw=orientation, host=host, port=port, counts_per_mm=cpm,
            straight_length_mm=straight, max_contraction_mm=max_c, winch_speed_mm_s=speed,
            color=color, parent=parent,
            parent_offset_position_m=offset_pos, parent_offset_orientation_xyzw=offset_q,
            index=i, tag_id=tag_id))
    for i, m in enumerate(modules):
        if m.parent is not None and m.parent not in seen_names:
            chk.fail(f'modules[{i}].parent', f'the name of another module ({", ".join(seen_names)})',
                     m.parent)
        # Walk up the chain: a cycle would make the base poses undefined.
        visited, cur = {m.name}, m
        while cur.parent is not None:
            cur = modules[seen_names[cur.parent]]
            if cur.name in visited:
                chk.fail(f'modules[{i}].parent', 'a chain without cycles', m.parent)
            visited.add(cur.name)
        if m.parent is not None:
            _check_chained_pose(chk, i, m, modules[seen_names[m.parent]], skeleton)

    gaits = chk.mapping(data['gaits'], 'gaits')
    if not gaits:
        chk.fail('gaits', 'at least one gait', gaits)
    frozen_gaits = {}
    for gname, spec in gaits.items():
        chk.identifier(gname, f'gaits.{gname}')
        chk.mapping(spec, f'gaits.{gname}')
        chk.string(spec.get('type'), f'gaits.{gname}.type')
        frozen_gaits[gname] = _freeze(spec)
    default_gait = chk.string(data['default_gait'], 'default_gait')
    if default_gait not in frozen_gaits:
        chk.fail('default_gait', f'one of the gaits ({", ".join(frozen_gaits)})', default_gait)

    return Scene(name=name, description=description.strip(), connector=_freeze(connector),
                 modules=tuple(modules), gaits=MappingProxyType(frozen_gaits),
                 skeleton=skeleton, default_gait=default_gait, path=path, frame=frame.strip(),
                 _by_name=MappingProxyType({m.name: m for m in modules}))


def _freeze(value):
    """Read-only deep copy of parsed YAML: mappings -> MappingProxyType, lists -> tuples."""
    if isinstance(value, Mapping):
        return MappingProxyType({k: _freeze(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(_freeze(v) for v in value)
    return value
