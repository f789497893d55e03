"""Spin a node's executor until Ctrl-C, SIGTERM or an external shutdown, for every main().

rclpy's signal handler shuts the context down on SIGINT. When that happens while the
executor is between two waits, rclpy raises ``RCLError`` ("the given context is not
valid") instead of ``ExternalShutdownException``; a ``main`` catching only the latter
then dies with a traceback and exit status 1 on an ordinary Ctrl-C (seen with the rerun
logger). Here any exception raised once the context is no longer ok is that shutdown.
"""
from __future__ import annotations

import contextlib
import gc
import os
import signal
import sys
import threading
import time
from typing import Callable, NoReturn

from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

from softsnap_ros.dds_profile import use_node_profile
from softsnap_ros.lifeline import supervise


def init_ros(**init_kwargs) -> None:
    """``rclpy.init(**init_kwargs)`` with the nodes' Fast DDS profile (every node's main).

    First the process is tied to its supervisor (:func:`softsnap_ros.lifeline.supervise`):
    it gets SIGTERM, its ordinary shutdown, when its parent dies by any signal, when the
    lifeline pipe of a supervisor that passed one ends, and on SIGHUP.
    """
    import rclpy

    supervise()
    use_node_profile()
    rclpy.init(**init_kwargs)


#: How long an exception out of spin() waits for a shutdown already under way (s).
SHUTDOWN_GRACE_S = 2.0


def _sigint_shuts_down() -> bool:
    """Whether rclpy's own SIGINT handler is installed (it then shuts the contexts down)."""
    from rclpy.signals import SignalHandlerOptions, get_current_signal_handlers_options

    return get_current_signal_handlers_options() in (SignalHandlerOptions.SIGINT,
                                                     SignalHandlerOptions.ALL)


def _await_shutdown(context) -> None:
    """Wait up to SHUTDOWN_GRACE_S for ``context`` to be shut down."""
    deadline = time.monotonic() + SHUTDOWN_GRACE_S
    while context.ok() and time.monotonic() < deadline:
        time.sleep(0.01)


def spin_until_shutdown(executor: Executor) -> None:
    """``executor.spin()``; returns normally when the context was shut down.

    On SIGINT rclpy's signal thread first triggers every executor's signal guard
    condition, then shuts the contexts down, while Python raises KeyboardInterrupt in
    the main thread, possibly before that thread is done. The executor (and with it that
    guard condition, through its ``__del__`` or ``shutdown()``) must not go while the
    signal thread may still trigger it: a guard condition destroyed under it is a use
    after free: the likely cause of a driver_container's SIGSEGV (-11) on the physics
    demo's SIGINT in a CI run, and reproduced with the window widened
    (benchmarks/sigint_race_stress.py). So a KeyboardInterrupt returns once the context
    is shut down (rclpy's handler installed, within SHUTDOWN_GRACE_S), which the signal
    thread does last.

    Any other exception out of ``spin()`` is a shutdown if the context is shut down, or
    is within SHUTDOWN_GRACE_S: a take racing with rclpy's signal thread ended model_node
    with exit status 1 ("Unable to convert call argument '0' to Python object" from
    ``take_message``, a clean-clone CI run, loaded machine) while the context was still
    ok. A real failure is raised after that wait.
    """
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
    except KeyboardInterrupt:
        if _sigint_shuts_down():
            _await_shutdown(executor.context)
    except Exception:
        _await_shutdown(executor.context)
        if executor.context.ok():
            raise  # a real failure, not a shutdown


#: After ROS is closed, how long a fast exit keeps the process before it ends (s), and
#: the latest it ends, counted from when spinning ended (s): see exit_without_teardown.
EXIT_LINGER_S = 0.8
EXIT_BY_S = 1.5


def exit_without_teardown(status: int, context, spinning_ended: float) -> NoReturn:
    """Close the ROS context, then end the process without Python's interpreter teardown.

    For nodes whose every resource is already closed (ROS shut down, files flushed):
    SIGINT must end them within 2 s, and the interpreter's teardown of numpy, rclpy,
    rerun and the message modules alone took 0.3 s idle and up to 2.4 s on the loaded
    2-core machine, with nothing in it that anyone outside the process could notice.

    The process first stays ``EXIT_LINGER_S``, never past ``spinning_ended + EXIT_BY_S``
    (monotonic s): ended at once, 2 of 39 model_node exits during two long designs on
    the loaded machine stayed in a peer's ROS graph until the DDS lease ran out (20 s),
    0 of 70 with a 0.3 s linger, and then 1 in a clean-clone CI run with other tests
    loading the machine (exit after 0.42 s): the linger is now 0.8 s. Why is not proven:
    the participant and its threads are gone by then, so the farewell was sent; the
    likely loss is a reader that had not yet read it from the shared-memory transport,
    whose data lives in the writer's process.
    Output is flushed first.
    """
    gc.collect()  # drop the last references to ROS handles so the context can go
    context.destroy()
    sys.stdout.flush()
    sys.stderr.flush()
    time.sleep(max(0.0, min(EXIT_LINGER_S, spinning_ended + EXIT_BY_S - time.monotonic())))
    os._exit(status)


@contextlib.contextmanager
def _signals_held():
    """While a node stops (its driver's confirmed stop, files closed), a second SIGINT,
    SIGTERM or SIGHUP (Ctrl-C pressed again, a supervisor escalating) is noted instead of
    raising KeyboardInterrupt in the middle of the stop: the process is already ending.
    Not restored: what follows is the exit."""
    hold_signals()
    yield
    hold_signals(final=True)


def hold_signals(final: bool = False) -> None:
    """From now on SIGINT, SIGTERM and SIGHUP only print that the process is stopping.

    ``final`` (call it after ``rclpy.try_shutdown``, which puts back the handlers rclpy
    had replaced): they are ignored from then on. A Python handler is reset to the
    default action by the interpreter's teardown, and a Ctrl-C then, while numpy and
    rclpy are torn down (up to 2 s on a loaded machine), ended the process by SIGINT
    (exit status -2); an ignored signal stays ignored.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if final:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_IGN)
        return

    def noted(signum, _frame):
        print(f'[{os.path.basename(sys.argv[0]) or "node"}] {signal.Signals(signum).name} '
              'while stopping: already stopping', file=sys.stderr, flush=True)

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, noted)


def inbox_node(name: str, namespace: str, context) -> Node:
    """A node whose subscriptions a thread of its own takes from, which no executor spins
    (the drivers' CommandInbox, model_node's PredictionThread); its node-local remap keeps
    a process-wide `-r __node:=NAME` from giving it another name."""
    return Node(name, namespace=namespace, context=context, start_parameter_services=False,
                enable_rosout=False, cli_args=['--ros-args', '-r', f'__node:={name}'])


def _spin_nodes(nodes) -> None:
    """Serve ``nodes`` with one single-threaded executor until the context shuts down."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    spin_until_shutdown(executor)


#: After its shutdown signal a simulator keeps serving its modules while a client still
#: talks to it, until no request came for SIM_LINGER_IDLE_S, at most SIM_LINGER_MAX_S:
#: under ``ros2 launch`` Ctrl-C reaches every node at once, and a simulator gone in the
#: same instant as its driver refused the driver's last act, its confirmed stop (every
#: driver logged "stop NOT confirmed ... refused the connection").
SIM_LINGER_IDLE_S = 0.3
SIM_LINGER_MAX_S = 1.2


def linger_while_served(served: Callable[[], int], idle_s: float = SIM_LINGER_IDLE_S,
                        max_s: float = SIM_LINGER_MAX_S) -> float:
    """Wait while ``served()`` (requests answered so far) still grows; the seconds waited."""
    start = time.monotonic()
    last, quiet_since = served(), start
    while time.monotonic() - start < max_s and time.monotonic() - quiet_since < idle_s:
        time.sleep(0.02)
        count = served()
        if count != last:
            last, quiet_since = count, time.monotonic()
    return time.monotonic() - start


def run_simulator_main(argv: list[str] | None, name: str, build_parser: Callable,
                       make_node: Callable, stop_node: Callable,
                       served: Callable | None = None) -> int:
    """``main()`` of a simulator node whose plain options give its parameters' defaults.

    ``make_node(defaults)`` builds the node from the parsed plain options (those before
    ``--ros-args``); one single-threaded executor serves it until Ctrl-C, SIGTERM or an
    external shutdown (the simulator's own threads do the work). Bad parameters or a
    port in use end it with one fatal line and exit status 2. ``stop_node(node)``
    destroys the node, prints what it did and returns an exit status (0 when clean).
    ``served(node)``, if given, counts the requests the simulator answered: after a
    shutdown signal it serves on while they still come (:func:`linger_while_served`).
    """
    import rclpy
    from rclpy.utilities import remove_ros_args

    argv = sys.argv if argv is None else argv
    defaults = build_parser().parse_args(remove_ros_args(argv)[1:])
    init_ros(args=argv)
    node = None
    status = 0
    try:
        node = make_node(defaults)
        _spin_nodes([node])
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError) as exc:   # bad parameters or scene, port in use: exit 2
        rclpy.logging.get_logger(name).fatal(f'cannot start: {exc}')
        status = 2
    finally:
        with _signals_held():
            if node is not None and served is not None and status == 0:
                linger_while_served(lambda: served(node))
            if node is not None:
                status = stop_node(node) or status
            rclpy.try_shutdown()
    return status


def run_node_main(args: list[str] | None, name: str, make_node: Callable[[], Node],
                  make_executor: Callable[[], Executor] | None = None,
                  fast_exit: bool = False) -> int:
    """``main()`` of a process serving one node: build it, spin until shutdown, stop.

    A ``ValueError`` while building (a bad scene or parameter) is logged as fatal and ends
    with exit status 2; a Ctrl-C while building (rclpy shut the context down under the
    constructor) is a clean stop, exit 0. A second Ctrl-C while stopping prints no
    traceback (hold_signals). `make_executor` defaults to a single-threaded executor.
    `fast_exit`: once the node is destroyed, end the process without the interpreter's
    teardown (:func:`exit_without_teardown`; for nodes with daemon worker threads or heavy
    imports that must stop within 2 s of SIGINT).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    init_ros(args=args)
    node = None
    status = 0
    stopped = time.monotonic()
    try:
        try:
            node = make_node()
        except ValueError as exc:
            rclpy.logging.get_logger(name).fatal(f'cannot start: {exc}')
            status = 2
        except Exception:   # noqa: BLE001 - rclpy's RCLError once the context is gone
            if rclpy.ok():   # not a Ctrl-C while starting
                raise
        if node is not None:
            executor = (make_executor or SingleThreadedExecutor)()
            executor.add_node(node)
            try:
                spin_until_shutdown(executor)
            finally:
                stopped = time.monotonic()
                executor.shutdown()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        hold_signals()   # a second Ctrl-C while stopping: no traceback
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        hold_signals(final=True)   # ignored from here to the exit
    if fast_exit and node is not None:
        exit_without_teardown(status, node.context, stopped)
    return status


def run_nodes_main(args: list[str] | None, program: str, build: Callable) -> int:
    """``main()`` of a process whose nodes are served by one single-threaded executor.

    ``build(at_exit)`` creates the nodes and returns them; it registers with
    ``at_exit(callable)`` what must run at exit (stops, ``destroy_node``), as soon as
    the thing exists, so a failure half way through still cleans up what was started.
    Cleanups run in reverse order; one that returns a non-zero int (a driver whose last
    stop was not confirmed) makes that the exit status, the highest one wins. A ``ValueError`` while building (a bad argument) is
    printed after the program's name and ends with exit status 2.
    """
    import rclpy

    cleanups: list[Callable] = []
    status = 0
    init_ros(args=args)
    try:
        _spin_nodes(build(cleanups.append))
    except KeyboardInterrupt:
        pass
    except ValueError as exc:
        print(f'{program}: {exc}', file=sys.stderr)
        status = 2
    finally:
        with _signals_held():
            for cleanup in reversed(cleanups):
                status = max(status, cleanup() or 0)
            rclpy.try_shutdown()
    return status
