"""Where the viewer listens unless told otherwise (no imports: the command line reads these for its --help)."""

from __future__ import annotations

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT"]

DEFAULT_HOST = "127.0.0.1"
"""Bind address: this machine only (reach it from elsewhere with ``ssh -L``, or bind 0.0.0.0)."""
DEFAULT_PORT = 8080
"""Port of the page and its websocket (viser serves both on one port)."""
