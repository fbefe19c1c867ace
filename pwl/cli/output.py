"""What several commands print the same way: optional plots and flat result dicts."""
from __future__ import annotations

import json

NO_PLOT = "(no plot: install the plot extra, pip install -e '.[plot]')"


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
