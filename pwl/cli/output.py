"""What several commands do the same way: check output paths up front, optional plots and flat
result dicts."""
from __future__ import annotations

import json
import os
import tempfile

from ..errors import PwlError

NO_PLOT = "(no plot: install the plot extra, pip install -e '.[plot]')"


class OutputPathError(PwlError):
    """An output file or folder that cannot be written (the message names it and says why)."""


def check_output(path, folder: bool = False) -> None:
    """Make sure ``path`` (a file, or with ``folder`` a folder) can be written, before any
    computation: the folder that will hold it is created if missing and must take a new file; an
    existing file must be writable and not a folder. Nothing to do for an empty path (no output).
    Raises :class:`OutputPathError` naming the path."""
    if not path:
        return
    path = os.fspath(path)
    target = path if folder else os.path.dirname(os.path.abspath(path))
    if not folder and os.path.isdir(path):
        raise OutputPathError(f"{path}: is a folder; give a file name")
    if not folder and os.path.exists(path) and not os.access(path, os.W_OK):
        raise OutputPathError(f"{path}: the file exists and cannot be overwritten (permission denied)")
    try:
        os.makedirs(target, exist_ok=True)
    except OSError as e:
        raise OutputPathError(f"{path}: cannot create the folder {target} ({e.strerror or e})") from None
    try:  # a probe file: permissions alone miss read-only file systems (and root ignores them)
        with tempfile.TemporaryFile(dir=target):
            pass
    except OSError as e:
        raise OutputPathError(f"{path}: the folder {target} is not writable ({e.strerror or e})") from None


def plot_or_note(plot, path, *args, lead: str = "", file=None) -> bool:
    """``plot(*args, path)`` (a matplotlib figure writer); without matplotlib, print how to get it
    instead. ``lead`` is printed before the message (e.g. a blank line); ``file``: where the
    message goes (default stdout; stderr when stdout carries JSON). True if written."""
    try:
        plot(*args, path)
    except ImportError:
        print(f"{lead}{NO_PLOT}", file=file)
        return False
    print(f"{lead}plot: {path}", file=file)
    return True


def print_result(res: dict, as_json: bool) -> None:
    """A flat dict as indented JSON, or one aligned ``name: value`` line each (floats to 4
    significant digits)."""
    if as_json:
        print(json.dumps(res, indent=2))
        return
    w = max(map(len, res), default=0)
    for k, v in res.items():
        print(f"{k:>{w}}: {v:,.4g}" if isinstance(v, float) else f"{k:>{w}}: {v}")
