"""The interactive viewer in a notebook: the page `blueshift view` serves, embedded in an
iframe.

Why an iframe and not an anywidget: the viewer is already a page with its own WebSocket
protocol, token and progressive frame stream; an iframe to the server this kernel runs
shows exactly that page, with no second front end to keep in step and no Jupyter comm in
the frame path (frames go browser <-> server directly). The server binds loopback with a
random token, so the notebook's browser must run on the kernel's machine (or reach it
through an SSH tunnel of the port).
"""

from __future__ import annotations

import html
from typing import Any


class Viewer:
    """A running viewer: ``url`` (with its token), ``stop()``; shows itself in an iframe."""

    def __init__(self, native: Any, height: int = 640) -> None:
        self._native = native
        self.height = height

    @property
    def url(self) -> str:
        return self._native.url

    @property
    def running(self) -> bool:
        return self._native.running

    def stop(self) -> None:
        """Stops serving; open pages lose their connection."""
        self._native.stop()

    def _repr_html_(self) -> str:
        u = html.escape(self.url, quote=True)
        return (
            f'<iframe src="{u}" width="100%" height="{int(self.height)}" '
            'style="border:0" allow="clipboard-write"></iframe>'
        )

    def __repr__(self) -> str:
        return f"Viewer(url={self.url!r}, running={self.running})"

    def __enter__(self) -> "Viewer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
