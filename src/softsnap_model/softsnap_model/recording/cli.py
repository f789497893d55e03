"""``python -m softsnap_model.recording {sweep,threadings,view}`` and ``softsnap-model record``."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import rerun as rr

from ..rrd_check import require_recording
from ..skeleton import Skeleton
from .paths import APPLICATION_ID
from .stream import serve_web_viewer
from .sweeps import parse_threading, record_sweep, record_threadings


def add_record_arguments(parser: argparse.ArgumentParser):
    """Arguments of the ``record`` command (for a ``softsnap-model record`` subcommand).

    Returns the subparsers object so callers can add more commands beside these.
    """
    sub = parser.add_subparsers(dest='what', required=True)
    sweep = sub.add_parser('sweep', help="one module's shapes over a range of contractions")
    sweep.add_argument('--threading', required=True, help='e.g. "R3x12" or "R1 R1 ... R3"')
    compare = sub.add_parser('threadings', help='several threadings side by side')
    compare.add_argument('--threading', action='append', required=True, metavar='NAME=HOLES',
                         help='repeat per threading, e.g. --threading s="R3x6 L3x6"')
    for p in (sweep, compare):
        p.add_argument('--max-contraction-mm', type=float, default=40.0,
                       help='largest cable contraction of the sweep (mm, default 40)')
        p.add_argument('--steps', type=int, default=41, help='number of contractions (41)')
        p.add_argument('--out', required=True, help='.rrd file to write')
    return sub


def run_record(args: argparse.Namespace) -> Path:
    """Carry out a parsed ``record`` command; returns the path written."""
    if args.steps < 1 or not args.max_contraction_mm >= 0.0:
        raise ValueError(f'need steps >= 1 and max contraction >= 0 mm, got {args.steps} '
                         f'and {args.max_contraction_mm}')
    contractions = np.linspace(0.0, args.max_contraction_mm, args.steps).tolist()
    if args.what == 'sweep':
        path = record_sweep(args.out, parse_threading(args.threading), contractions)
    else:
        named = {}
        for item in args.threading:
            name, sep, holes = item.partition('=')
            if not sep:
                raise ValueError(f'expected NAME=HOLES, got {item!r}')
            named[name.strip()] = parse_threading(holes)
        path = record_threadings(args.out, named, contractions)
    return path


def add_cli(subparsers):
    """Register ``softsnap-model record {sweep,threadings}`` (see :mod:`softsnap_model.cli`)."""
    parser = subparsers.add_parser(
        'record', help='write a rerun recording without ROS (a sweep, or threadings compared)')
    add_record_arguments(parser)
    parser.set_defaults(handler=_cli_handler)


def _cli_handler(args: argparse.Namespace, skeleton) -> dict:
    if skeleton != Skeleton():
        raise ValueError('record draws the authors\' module only; --skeleton is not supported')
    return {'recording': str(run_record(args).resolve()), 'steps': args.steps}


def serve_recording(path: str | Path, *, web_port: int = 9090, grpc_port: int = 9876,
                    online: bool = False) -> tuple[str, rr.RecordingStream]:
    """Serve an .rrd file to rerun's bundled web viewer; returns (url, stream).

    The viewer's files come from the installed rerun-sdk; a browser opening the url gets
    the recording over gRPC from this process. Keep the returned stream (and the process)
    alive while the page is open. Unless `online`, nothing leaves this machine: no
    analytics, no web fonts, no examples list (:mod:`softsnap_model.viewer_offline`).
    """
    path = Path(path)
    require_recording(path)   # not a recording: a ValueError; cut short or damaged: a warning
    if not online:
        from .. import viewer_offline
        viewer_offline.disable_analytics()   # before rerun's native side starts its sinks
    rec = rr.RecordingStream(f'{APPLICATION_ID}_view')
    rec.serve_grpc(grpc_port=grpc_port)
    rec.log_file_from_path(path)
    if online:
        return serve_web_viewer(web_port, grpc_port), rec
    grpc_url = f'rerun+http://127.0.0.1:{int(grpc_port)}/proxy'
    return viewer_offline.serve_offline(web_port, grpc_url), rec


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m softsnap_model.recording {sweep,threadings,view} ...``."""
    parser = argparse.ArgumentParser(prog='python -m softsnap_model.recording',
                                     description='Write or view rerun recordings without ROS.')
    sub = add_record_arguments(parser)
    view = sub.add_parser('view', help="serve an .rrd to rerun's web viewer (offline)")
    view.add_argument('file', help='.rrd recording')
    view.add_argument('--web-port', type=int, default=9090)
    view.add_argument('--grpc-port', type=int, default=9876)
    view.add_argument('--online', action='store_true',
                      help="rerun's defaults: its analytics, web fonts and examples list "
                           '(default: offline, nothing leaves this machine)')
    args = parser.parse_args(argv)
    try:
        if args.what != 'view':
            print(f'wrote {run_record(args)}')
            return 0
        url, _stream = serve_recording(args.file, web_port=args.web_port,
                                       grpc_port=args.grpc_port, online=args.online)
        print(f'open {url}  (Ctrl-C to stop)', flush=True)
        try:
            # Short sleeps: a Ctrl-C the kernel hands to one of rerun's threads only sets
            # Python's flag, and a long sleep of the main thread would not see it for an
            # hour (a test saw `view` ignore SIGINT that way).
            while True:
                time.sleep(0.2)
        except KeyboardInterrupt:
            return 0
    except (ValueError, RuntimeError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
