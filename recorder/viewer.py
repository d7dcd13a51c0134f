"""Live viewing: where a recording's Rerun stream goes besides its .rrd file.

`Recorder(..., viewer=True)` streams the run to a Rerun Viewer while it writes the files: to a
viewer already listening on this machine's default port (`DEFAULT_PORT`), else to one it starts
(`rerun.spawn`, which needs a display and the `rerun` program next to Python or on PATH; the viewer
stays open after the run). `viewer="rerun+http://HOST:PORT/proxy"` streams to the viewer (or
`rerun --serve-grpc` proxy) at that address instead.

When no viewer can be reached or started, one `ViewerWarning` line says why and the run is
recorded to its files only. The files do not depend on the viewer: the live stream is a second
Rerun `RecordingStream` (same application and recording id), so the .rrd is written exactly as
without a viewer. A viewer that cannot be reached is found out before the run (TCP connect, 1 s at
most); one that goes away during the run never blocks a step (rerun-sdk does not report it: the
stream buffers), and the end of the run waits at most 2 s for the live stream.
"""

from __future__ import annotations

import inspect
import os
import shutil
import socket
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

#: Where rerun-sdk's viewer listens by default (`rerun.spawn`, `rerun` without arguments).
DEFAULT_PORT = 9876
_SCHEMES = ("rerun", "rerun+http", "rerun+https")
_CONNECT_TIMEOUT_S = 1.0


class ViewerWarning(UserWarning):
    """No live viewer for this run (none reachable, none could be started, or it went away)."""


@dataclass(frozen=True)
class ViewerTarget:
    """Stream to `url`; `spawn`: start a viewer there first (`executable` is the `rerun` program)."""

    url: str
    spawn: bool = False
    executable: Path | None = None

    @property
    def port(self) -> int:
        return urlsplit(self.url).port


def warn(message: str) -> None:
    """One line: why the run has no live viewer; attributed to the caller's code outside this package."""
    frame, level = inspect.currentframe(), 1
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] == "recorder":
        frame, level = frame.f_back, level + 1
    warnings.warn(message, ViewerWarning, stacklevel=level)


def local_url(port: int) -> str:
    return f"rerun+http://127.0.0.1:{port}/proxy"


def listening(host: str, port: int, timeout: float = _CONNECT_TIMEOUT_S) -> bool:
    """Whether something accepts TCP connections at host:port."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def rerun_executable() -> Path | None:
    """The `rerun` program of this Python environment, else the one on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file() and os.access(beside, os.X_OK):
        return beside
    found = shutil.which("rerun")
    return Path(found) if found else None


def no_display_reason() -> str | None:
    """Why a native viewer window cannot open here (Linux without X11/Wayland), else None."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    return None


def check_url(url: str) -> tuple[str, int]:
    """(host, port) of a viewer URL; ValueError naming the URL if it is not rerun+http(s)://HOST:PORT/proxy."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in _SCHEMES or not parts.hostname or port is None or parts.path != "/proxy":
        raise ValueError(f"viewer {url!r} must be True, False or a URL like {local_url(DEFAULT_PORT)}")
    return parts.hostname, port


def resolve(viewer: bool | str, *, port: int = DEFAULT_PORT) -> ViewerTarget | None:
    """Where to stream for `Recorder(viewer=...)`, or None (after a `ViewerWarning` saying why).

    False: None. A URL: that viewer if it accepts connections. True: a viewer listening on
    127.0.0.1:`port`, else one to spawn there when a display and the `rerun` program exist.
    """
    if viewer is False or viewer is None:
        return None
    if isinstance(viewer, str):
        host, url_port = check_url(viewer)
        if not listening(host, url_port):
            warn(f"no Rerun viewer listening at {viewer}; recording to files only")
            return None
        return ViewerTarget(viewer)
    if viewer is not True:
        raise ValueError(f"viewer {viewer!r} must be True, False or a URL like {local_url(DEFAULT_PORT)}")
    url = local_url(port)
    if listening("127.0.0.1", port):
        return ViewerTarget(url)
    reason = no_display_reason()
    executable = rerun_executable()
    if reason is None and executable is None:
        reason = "the `rerun` program is not installed"
    if reason is not None:
        warn(f"cannot start a Rerun viewer: {reason}; recording to files only")
        return None
    return ViewerTarget(url, spawn=True, executable=executable)
