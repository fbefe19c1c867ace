"""The fleet at a glance: every engine's diagnosis at every flight in one chart
(``pwl fleet diagnose --plot``), the rows of ``diagnosis.csv`` an engineer would rather see than
read."""
from __future__ import annotations

import numpy as np

from .diagnose import Decision, _natural

#: the chart's states before the classes found: (name, colour)
STATES = (("baseline", "#d9d9d9"), ("no fault", "#e5f5e0"), ("not diagnosed", "#737373"),
          ("recovery / bias gone", "#9ecae1"))
_NOT_DIAGNOSED = ("no steady snapshot", "excluded")


def _state(d: Decision) -> str:
    """The chart's name of one row: its class when a fault is detected, else its state."""
    if d.detected:
        return d.cls
    if d.status == "baseline":
        return STATES[0][0]
    if d.status in _NOT_DIAGNOSED:
        return STATES[2][0]
    if d.status in ("recovery", "cleared"):
        return STATES[3][0]
    return STATES[1][0]


def fleet_grid(rows: list[Decision], every: bool = False) -> tuple[list[str], np.ndarray, np.ndarray, list[str]]:
    """(engines, flight numbers (F,), codes (E, F), names) of the diagnosis ``rows``: ``codes[e, f]``
    indexes ``names`` (the :data:`STATES`, then the classes detected, in the order first seen),
    -1 where engine e has no row at flight number f. Engines: those with a finding at any flight
    (a fault, a recovery, a bias gone), in natural order of their serials; with ``every``, all."""
    names = [s for s, _ in STATES]
    by_engine: dict[str, list[Decision]] = {}
    for d in rows:
        by_engine.setdefault(d.engine, []).append(d)
        if _state(d) not in names:
            names.append(_state(d))
    shown = [e for e in sorted(by_engine, key=_natural)
             if every or any(_state(d) not in (STATES[0][0], STATES[1][0], STATES[2][0]) for d in by_engine[e])]
    flights = np.array(sorted({d.flight for e in shown for d in by_engine[e]}), dtype=np.int64)
    codes = np.full((len(shown), flights.size), -1, dtype=np.int64)
    for i, e in enumerate(shown):
        for d in by_engine[e]:
            codes[i, np.searchsorted(flights, d.flight)] = names.index(_state(d))
    return shown, flights, codes, names


def plot_fleet(rows: list[Decision], path, every: bool = False) -> None:
    """PNG of :func:`fleet_grid`: an engine a line, a flight a column, a colour per state and per
    class found (its kinds in the legend: step, drift, level, ...); the onset of the fault each
    engine has at its latest flight marked with a black bar (matplotlib, the ``plot`` extra)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    engines, flights, codes, names = fleet_grid(rows, every)
    classes = names[len(STATES):]
    # a qualitative palette without its greens and greys (the states'), in the order first seen
    tab = plt.get_cmap("tab20")
    hues = [tab(k) for k in range(20) if k not in (4, 5, 14, 15)]
    colour = {c: hues[k % len(hues)] for k, c in enumerate(classes)}
    kinds: dict[str, list[str]] = {}
    for d in rows:
        if d.detected and d.kind not in kinds.setdefault(d.cls, []):
            kinds[d.cls].append(d.kind)
    palette = ["white"] + [c for _, c in STATES] + [colour[c] for c in classes]
    height = 1.2 + 0.22 * max(len(engines), 1)
    fig, ax = plt.subplots(figsize=(min(4.0 + 0.12 * max(flights.size, 1), 16.0), min(height, 40.0)))
    if engines:
        ax.imshow(codes + 1, cmap=ListedColormap(palette), vmin=0, vmax=len(palette) - 1, aspect="auto",
                  interpolation="nearest", extent=(flights[0] - 0.5, flights[-1] + 0.5, len(engines) - 0.5, -0.5))
        latest = {}
        for d in rows:
            latest[d.engine] = d                    # rows are in flight order per engine
        for i, e in enumerate(engines):
            d = latest[e]
            if d.detected and d.onset >= 0:
                ax.plot([d.onset - 0.5] * 2, [i - 0.45, i + 0.45], color="black", lw=1.5)
        ax.set_yticks(range(len(engines)), engines, fontsize=7)
    else:
        ax.text(0.5, 0.5, "no engine with a finding", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("flight")
    ax.xaxis.get_major_locator().set_params(integer=True)
    shown = [k for k in range(len(names)) if (codes == k).any()]
    label = [f"{n} ({', '.join(kinds[n])})" if n in kinds else n for n in names]
    ax.legend(handles=[Patch(color=palette[k + 1], label=label[k]) for k in shown], fontsize=7,
              loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    total = len({d.engine for d in rows})
    ax.set_title(f"{len(engines)} of {total} engines" + ("" if every else " (those with a finding)") +
                 "; black bar: onset of the fault at the latest flight", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
