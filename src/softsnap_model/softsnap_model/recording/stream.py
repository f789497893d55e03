"""Opening, serving, stamping and closing a rerun recording stream."""
from __future__ import annotations

from pathlib import Path
from urllib.parse import quote

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .paths import APPLICATION_ID, TIMELINE


def open_recording(output: str | Path | None = None, viewer_url: str | None = None, *,
                   serve_grpc_port: int | None = None, serve_bind_ip: str = '127.0.0.1',
                   blueprint: rrb.Blueprint | None = None,
                   application_id: str = APPLICATION_ID,
                   recording_id: str | None = None) -> rr.RecordingStream:
    """A recording stream writing to any of: a file, a running viewer, a hosted server.

    Parameters
    ----------
    output:
        .rrd file; its parent directories are created.
    viewer_url:
        rerun gRPC address of a running viewer, e.g. ``rerun+http://127.0.0.1:9876/proxy``.
    serve_grpc_port, serve_bind_ip:
        Host a gRPC server on this port that viewers (native, or the web viewer started
        with :func:`serve_web_viewer`) connect to. It keeps up to 1 GiB for late viewers.

    At least one sink must be given. Close the stream with :func:`close_recording` so the
    file gets its footer.
    """
    sinks = []
    if output is not None:
        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(output)))
    if viewer_url:
        sinks.append(rr.GrpcSink(viewer_url))
    if serve_grpc_port:
        sinks.append(rr.GrpcServerSink(bind_ip=serve_bind_ip, port=int(serve_grpc_port)))
    if not sinks:
        raise ValueError('open_recording needs an output file, a viewer_url or a '
                         'serve_grpc_port')
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    rec.set_sinks(*sinks, default_blueprint=blueprint)
    return rec


def serve_web_viewer(web_port: int, grpc_port: int, host: str = '127.0.0.1') -> str:
    """Serve rerun's bundled web viewer (offline) pointed at a gRPC server; returns its url."""
    grpc_url = f'rerun+http://{host}:{int(grpc_port)}/proxy'
    rr.serve_web_viewer(web_port=int(web_port), open_browser=False, connect_to=grpc_url)
    return f'http://{host}:{int(web_port)}/?url={quote(grpc_url, safe="")}'


def close_recording(rec: rr.RecordingStream, timeout_s: float = 10.0) -> None:
    """Flush everything logged so far and close the sinks (the file gets its footer)."""
    rec.flush(timeout_sec=timeout_s)
    rec.disconnect()


def set_stamp(rec: rr.RecordingStream, stamp_ns: int, sim_time: bool = False) -> None:
    """Set the ``ros_time`` timeline for this thread: a timestamp (nanoseconds since the
    epoch), or with `sim_time` a duration (nanoseconds of simulated time, shown as
    seconds from the simulation's start rather than as a date in January 1970)."""
    if sim_time:
        rec.set_time(TIMELINE, duration=np.timedelta64(int(stamp_ns), 'ns'))
    else:
        rec.set_time(TIMELINE, timestamp=np.datetime64(int(stamp_ns), 'ns'))


def time_column(stamps_ns, sim_time: bool = False) -> rr.TimeColumn:
    """The ``ros_time`` column of `stamps_ns`, as `set_stamp` sets it."""
    if sim_time:
        return rr.TimeColumn(TIMELINE, duration=np.array(stamps_ns, dtype='timedelta64[ns]'))
    return rr.TimeColumn(TIMELINE, timestamp=np.array(stamps_ns, dtype='datetime64[ns]'))
