"""How recordings look: module colours and roles, line widths, the legend and the blueprints."""
from __future__ import annotations

import math
from typing import Iterable, Mapping, Sequence

import numpy as np
import rerun.blueprint as rrb

from .paths import LEGEND_ROOT, PLOTS_ROOT, ROBOT_ROOT

# Colour is identity, style is role. Each module keeps one hue everywhere (3D shapes and
# every plot): its scene colour (the paper's module colours), else its name when that
# is a colour, else the next free colour of MODULE_PALETTE. What a line is (commanded,
# predicted, measured) is shown by saturation and width, never by hue: the commanded
# shape (the target) is a thin muted "ghost" of the module's colour, the predicted shape
# (from the measured length: where the module is) is bold in its full colour. So a
# module called "blue" is blue and nothing else is.
NAMED_COLORS = {
    'blue': (40, 110, 240), 'orange': (245, 130, 20), 'green': (40, 175, 70),
    'red': (225, 45, 45), 'purple': (160, 85, 230), 'yellow': (235, 200, 0),
    'cyan': (0, 190, 210), 'magenta': (225, 60, 190), 'brown': (160, 100, 50),
    'grey': (150, 150, 150),
}

MODULE_PALETTE = ('blue', 'orange', 'green', 'red', 'purple', 'yellow', 'cyan', 'magenta',
                  'brown', 'grey')

#: Share of the module colour kept in a commanded (target) line; the rest is a middle
#: grey, so the target reads as a muted ghost of the bold predicted shape on the light
#: and on the dark viewer theme alike.
COMMANDED_BRIGHTNESS = 0.55

GHOST_BASE = (128, 128, 128)

#: Role styles: width factor of each role's lines (1 = bold). Plots use the same rule:
#: a commanded series is dim and thin, a measured or predicted series full and thick.
ROLE_WIDTH = {'commanded': 0.45, 'predicted': 1.0, 'measured': 1.0, 'simulated': 0.7}

ROLE_DESCRIPTION = {'commanded': 'thin, muted: the commanded shape or length (the target)',
                    'predicted': 'bold, full colour: the shape predicted from the measured '
                                 'length (where the module is)',
                    'measured': 'bold, full colour: the measured length',
                    'simulated': 'medium, dark shade: the shape simulated in MuJoCo '
                                 '(gravity, contact, dynamics)'}

#: Share of the module colour kept in a simulated line (a darker shade of it).
SIMULATED_SHADE = 0.6

CONNECTOR_COLOR = (110, 110, 110)

# Line radii in metres of the bold (predicted) role.
SPINE_RADIUS_M = 0.0022

RIB_RADIUS_M = 0.0009

CABLE_RADIUS_M = 0.0005

#: Series line widths in UI points of the bold role (plots).
SERIES_WIDTH = 2.5

RGB = tuple[int, int, int]


def module_colors(modules: Iterable[tuple[str, str]]) -> dict[str, RGB]:
    """Display colour of each module from (name, scene colour) pairs, in order.

    The scene colour wins if it is a known colour name (NAMED_COLORS), then the module's
    name if it is one; other modules take the next palette colour no module uses yet.

    >>> module_colors([('head', ''), ('body2', ''), ('blue', '')])
    {'head': (245, 130, 20), 'body2': (40, 175, 70), 'blue': (40, 110, 240)}
    """
    pairs = list(modules)
    chosen: dict[str, str | None] = {}
    for name, color in pairs:
        for candidate in (str(color or '').strip().lower(), name.lower()):
            if candidate in NAMED_COLORS:
                chosen[name] = candidate
                break
        else:
            chosen[name] = None
    used = {c for c in chosen.values() if c}
    free = [c for c in MODULE_PALETTE if c not in used] or list(MODULE_PALETTE)
    k = 0
    for name in chosen:
        if chosen[name] is None:
            chosen[name] = free[k % len(free)]
            k += 1
    return {name: NAMED_COLORS[c] for name, c in chosen.items()}


def color_name(rgb: RGB) -> str:
    """Name of a NAMED_COLORS colour (for legends); '' for any other."""
    return next((n for n, c in NAMED_COLORS.items() if c == tuple(rgb)), '')


def role_color(rgb: RGB, role: str) -> RGB:
    """The colour a role draws a module in: full colour, or a muted ghost for commanded."""
    if role not in ROLE_WIDTH:
        raise ValueError(f'role must be one of {tuple(ROLE_WIDTH)}, got {role!r}')
    if role == 'simulated':
        return shade(rgb, SIMULATED_SHADE)
    if role != 'commanded':
        return tuple(int(c) for c in rgb)
    a = COMMANDED_BRIGHTNESS
    return tuple(int(round(a * c + (1.0 - a) * g)) for c, g in zip(rgb, GHOST_BASE))


def shade(rgb: RGB, factor: float) -> RGB:
    """A darker shade (factor < 1) of a colour, for the cable inside the skeleton."""
    return tuple(int(round(c * factor)) for c in rgb)


def robot_bounds_m(points_m: Iterable[Sequence[float]]) -> tuple[tuple[float, float, float], float]:
    """(centre, radius) in metres of a set of points: what the default camera frames."""
    pts = np.asarray([[float(v) for v in p] for p in points_m], dtype=float).reshape(-1, 3)
    if pts.size == 0:
        raise ValueError('robot_bounds_m needs at least one point, got none')
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    radius = float(np.linalg.norm(pts - centre, axis=1).max())
    return tuple(float(c) for c in centre), max(radius, 0.05)


def scene_style(scene) -> tuple[dict[str, RGB], tuple[tuple[float, float, float], float]]:
    """Module colours and robot bounds of a softsnap_model Scene (all modules straight)."""
    from ..scene import straight_tip_pose
    colors = module_colors((m.name, m.color) for m in scene.modules)
    points = [m.base_position_m for m in scene.modules]
    points += [straight_tip_pose(m, scene.skeleton)[0] for m in scene.modules]
    return colors, robot_bounds_m(points)


#: The default camera looks down on the robot from this far above the centre of its
#: bounds, in bound radii (the 3D view is about as wide as tall; 55 degree field of view),
#: tilted this far from the vertical so the orbit keeps z up.
CAMERA_HEIGHT_RADII = 2.1

CAMERA_TILT_RAD = math.radians(12.0)


def top_down_eye(bounds: tuple[Sequence[float], float]) -> rrb.EyeControls3D:
    """Orbital camera above the centre of `bounds` (centre m, radius m), looking down."""
    centre, radius = bounds
    height = CAMERA_HEIGHT_RADII * radius
    position = (centre[0], centre[1] - height * math.tan(CAMERA_TILT_RAD), centre[2] + height)
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position,
                             look_target=tuple(centre), eye_up=(0.0, 0.0, 1.0))


def build_blueprint(colors: Mapping[str, RGB] | None = None,
                    bounds: tuple[Sequence[float], float] | None = None,
                    world_view: bool = False) -> rrb.Blueprint:
    """The layout: the robot in 3D and the legend on the left, the time series on the right.

    One plot per quantity; each takes a quantity subtree, so one blueprint fits every robot
    and module count. The plots draw no legend of their own (with ten series it would
    cover the data): the legend view names every module's colour and every role's style,
    and hovering a line names its series. With `bounds` (centre m, radius m: see
    `scene_style`) the 3D view starts looking down on the whole robot. With `world_view`
    the 3D view's origin is the world (the recording root) rather than the robot, so a
    robot whose ``robot`` transform moves (:func:`log_robot_pose`) is seen moving.
    """
    def plot(title: str, quantity: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=title, origin=f'{PLOTS_ROOT}/{quantity}',
                                  plot_legend=rrb.PlotLegend(visible=False))

    plots = rrb.Vertical(
        plot('Cable length (mm): commanded thin, measured bold', 'cable_length_mm'),
        plot('Tip error, commanded vs predicted (mm)', 'tip_error_mm'),
        plot('Solver time (ms): commanded thin, predicted bold', 'solve_time_ms'),
        plot('Battery (V)', 'battery_v'),
    )
    # The world view adds only what differs, so other recordings keep their view as is.
    world = {'origin': '/', 'contents': f'{ROBOT_ROOT}/**'} if world_view else {'origin': ROBOT_ROOT}
    scene = rrb.Spatial3DView(
        name='Robot from above: commanded thin and muted, predicted bold',
        eye_controls=None if bounds is None else top_down_eye(bounds), **world)
    legend = rrb.TextDocumentView(name='Legend', origin=LEGEND_ROOT)
    left = rrb.Vertical(scene, legend, row_shares=[4, 1])
    return rrb.Blueprint(rrb.Horizontal(left, plots, column_shares=[3, 2]),
                         collapse_panels=True)


def build_sweep_blueprint() -> rrb.Blueprint:
    """Layout of the no-ROS recordings: shapes in 3D, the swept quantities below."""
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Spatial3DView(name='Shapes', origin=ROBOT_ROOT),
            rrb.Horizontal(
                rrb.TimeSeriesView(name='Contraction (mm)', origin=f'{PLOTS_ROOT}/contraction_mm'),
                rrb.TimeSeriesView(name='Tip angle (deg)', origin=f'{PLOTS_ROOT}/tip_angle_deg'),
            ),
            row_shares=[3, 1],
        ),
        collapse_panels=True,
    )


def legend_markdown(colors: Mapping[str, RGB]) -> str:
    """The legend's text: which colour is which module, which style is which role, and
    the series of every plot (the plots draw no legend of their own)."""
    modules = ', '.join(f'**{name}** {color_name(rgb) or "rgb" + str(tuple(rgb))}'
                        if color_name(rgb) != name else f'**{name}**'
                        for name, rgb in colors.items())
    return (f'**Colour = module** (named at its base in 3D): {modules}.  \n'
            '**Style = role:** thin, muted = commanded (the target); bold, full colour = '
            'predicted from the measured length (3D, solver time) or measured (cable length).'
            f'  \n**Plots** (hover a line for its name): cable length, commanded and measured '
            f'of each module ({2 * len(colors)} lines); tip error ({len(colors)}); solver '
            f'time, commanded and predicted ({2 * len(colors)}); battery ({len(colors)}).')
