"""The viewer's entry point: read a result directory, start a viser server, serve until stopped.

viser serves its prebuilt three.js client over HTTP and the scene over a websocket on the same port; the page at
``http://HOST:PORT`` is the whole viewer, nothing to build or install on the client's side. The host defaults to
127.0.0.1 (this machine only); on a remote machine forward the port with ``ssh -L PORT:localhost:PORT host`` and
open ``http://localhost:PORT`` locally, or bind ``0.0.0.0`` to let the network reach it (docs/view.md).
"""

from __future__ import annotations

import contextlib
import errno
import io
import socket
import threading
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputValueError, MissingDependencyError, TorchhandError
from .defaults import DEFAULT_HOST, DEFAULT_PORT
from .frames import ViewData, load_view
from .gui import Timeline
from .scene import SceneNodes, build_scene

__all__ = ["ViewerHandle", "PortInUseError", "serve", "DEFAULT_HOST", "DEFAULT_PORT"]


class PortInUseError(TorchhandError, OSError):
    """The viewer cannot listen on the host and port asked for (in use, or an address this machine lacks)."""


@dataclass(frozen=True, eq=False)
class ViewerHandle:
    """A running viewer.

    server: the ``viser.ViserServer``; data: the :class:`~.frames.ViewData` drawn; nodes: the scene's nodes
    (:class:`~.scene.SceneNodes`); timeline: the panel (:class:`~.gui.Timeline`); verdicts: the per-frame checker
    verdicts (:class:`~.verdict.FrameVerdicts` per solution) or None; host, port: where it listens; url:
    ``http://host:port``
    """

    server: object
    data: ViewData
    nodes: SceneNodes
    timeline: Timeline
    verdicts: tuple | None
    host: str
    port: int
    url: str
    stopped: threading.Event = field(default_factory=threading.Event)

    @property
    def frame(self) -> int:
        """The frame shown."""
        return self.timeline.frame

    def set_frame(self, t: int) -> None:
        """Show frame ``t``; raises InputValueError outside 0..T-1."""
        if not 0 <= int(t) < self.data.frames:
            raise InputValueError(f"frame: expected 0..{self.data.frames - 1}, got {t}")
        self.timeline.set_frame(int(t))

    def set_solution(self, index: int | None) -> None:
        """Show solution ``index`` only (the XXX of sol_XXX), or all for None."""
        if index is not None:
            self.data.solution(index)
        self.timeline.set_solution(index)

    def link_positions(self, index: int, side: str) -> np.ndarray:
        """The positions the scene holds now for solution ``index``'s ``side`` hand: (M, 3), world, metres, one row
        per drawn link (:attr:`~.frames.LinkMeshes.link` order)."""
        return np.stack([np.asarray(node.position, dtype=np.float64)
                         for _, node in self.nodes.links[(index, side)]])

    def clients(self) -> int:
        """The number of browsers connected now."""
        return len(self.server.get_clients())

    def stop(self) -> None:
        """Stop playback and the server (the port is free afterwards); a second call does nothing."""
        if self.stopped.is_set():
            return
        self.stopped.set()
        self.timeline.close()
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()

    def wait(self) -> None:
        """Serve until Ctrl-C (KeyboardInterrupt) or :meth:`stop`, then stop."""
        try:
            while not self.stopped.wait(0.25):
                pass
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()


def serve(result_dir, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, solution: int | str | None = "all",
          check: bool = True, block: bool = True) -> ViewerHandle:
    """Show a result directory in the browser.

    result_dir: a result directory (``docs/result_format.md``)
    host, port: where to listen (port 0: any free port; ``handle.port`` says which)
    solution: the solution shown first, an index (the XXX of sol_XXX), or "all" / None for every solution
    check: run the checker (:mod:`torchhand.check`) and show its verdicts per frame on the timeline
    block: serve until Ctrl-C and stop (the handle is returned after); False: return at once, the server running
        in background threads until ``handle.stop()``
    Raises MissingFileError / FileFormatError / ShapeError for a missing or malformed result, InputValueError for a
    bad ``solution`` or port, PortInUseError when the port is taken, MissingDependencyError without viser.
    """
    try:
        import viser
    except ImportError:
        raise MissingDependencyError("torchhand view needs viser: pip install 'viser>=1.0'") from None
    if not isinstance(port, int) or not 0 <= port <= 65535:
        raise InputValueError(f"port: expected an integer 0..65535, got {port!r}")
    first = _solution(solution)
    data = load_view(result_dir)
    if first is not None:
        data.solution(first)
    verdicts = None
    if check:
        from .verdict import frame_verdicts

        verdicts = frame_verdicts(result_dir)
    _probe(host, port)
    with contextlib.redirect_stdout(io.StringIO()):     # viser's own banner: the caller prints the URL
        server = viser.ViserServer(host=host, port=port, label=f"torchhand view: {data.scene}", verbose=False)
    bound = int(server.get_port())
    if port != 0 and bound != port:     # viser moves on to the next free port; a viewer asked for one must not
        server.stop()
        raise PortInUseError(f"port {port} on {host} is in use; choose another with --port")
    try:
        # no share button: it would publish the scene through viser's relay server
        server.gui.configure_theme(control_width="large", show_share_button=False)
        nodes = build_scene(server, data)
        timeline = Timeline(server, data, nodes, verdicts, first)
    except BaseException:
        server.stop()
        raise
    shown = "localhost" if host in ("0.0.0.0", "::", "") else host
    handle = ViewerHandle(server=server, data=data, nodes=nodes, timeline=timeline, verdicts=verdicts, host=host,
                          port=bound, url=f"http://{shown}:{bound}")
    if block:
        handle.wait()
    return handle


def _solution(solution) -> int | None:
    if solution is None or (isinstance(solution, str) and solution.strip().lower() == "all"):
        return None
    try:
        value = int(solution)
    except (TypeError, ValueError):
        raise InputValueError(f"solution: expected an index or 'all', got {solution!r}") from None
    if value < 0:
        raise InputValueError(f"solution: expected an index >= 0 or 'all', got {solution!r}")
    return value


def _probe(host: str, port: int) -> None:
    """Raise PortInUseError unless a listening socket can be bound at (host, port) right now."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as err:
        raise PortInUseError(f"host {host!r}: not an address of this machine ({err.strerror})") from None
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise PortInUseError(f"port {port} on {host} is in use; choose another with --port") from None
            raise PortInUseError(f"cannot listen on {host}:{port}: {err.strerror}") from None
