"""The Rerun viewer process: is one listening, and can the SDK find the one we installed."""

from __future__ import annotations

import os
import shutil
import socket
import sys
import time
from pathlib import Path
from urllib.parse import urlsplit

__all__ = ["listening", "viewer_on_path"]


def listening(url: str, wait_s: float) -> bool:
    """True when something accepts TCP connections at the URL's host and port within
    ``wait_s`` seconds."""
    parts = urlsplit(url)
    try:
        host, port = parts.hostname or "127.0.0.1", parts.port or 9876
    except ValueError:  # a port out of range: nothing listens there
        return False
    deadline = time.monotonic() + wait_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=1.0):
                return True
        except OSError:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.2)


def viewer_on_path() -> None:
    """Put the ``rerun`` viewer installed beside this Python on PATH when PATH has none: the
    SDK looks it up by name, and ``.venv/bin`` is not on PATH unless the venv is activated."""
    if shutil.which("rerun") is None:
        here = Path(sys.executable).parent
        if (here / "rerun").is_file():
            os.environ["PATH"] = f"{here}{os.pathsep}{os.environ.get('PATH', '')}"
