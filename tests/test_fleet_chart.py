"""The fleet chart of ``pwl fleet diagnose --plot`` (pwl.fleet.chart): its grid against rows
written by hand, and the image drawn from it."""
import numpy as np
import pytest

from pwl.fleet.chart import STATES, fleet_grid, plot_fleet
from pwl.fleet.diagnose import Decision


def rows():
    def d(engine, flight, status="ok", cls="none", kind="", onset=-1):
        return Decision(engine, flight, f"flight {flight}", "x.csv", status, int(cls != "none"), cls, kind, onset)
    out = [d("E1", k, "baseline") for k in range(3)] + [d("E1", 3), d("E1", 4)]
    out += [d("E1", 5, cls="hpt", kind="step", onset=5), d("E1", 6, cls="hpt", kind="step", onset=5)]
    out += [d("E2", k, "baseline") for k in range(3)] + [d("E2", k) for k in range(3, 7)]
    out += [d("E10", 0, "baseline"), d("E10", 1, "baseline"), d("E10", 2, "excluded"),
            d("E10", 3, "recovery", kind="recovery", onset=3), d("E10", 4)]
    out += [d("E3", k, "baseline") for k in range(3)] + [d("E3", 4, cls="sensor:T48", kind="drift", onset=4)]
    return out


def test_the_grid_holds_every_row_where_its_engine_and_flight_are():
    engines, flights, codes, names = fleet_grid(rows())
    assert engines == ["E1", "E3", "E10"]            # natural order; E2 has no finding
    assert names == [s for s, _ in STATES] + ["hpt", "sensor:T48"]
    assert flights.tolist() == list(range(7))
    base, ok, off, back, hpt, t48 = range(6)
    assert codes.tolist() == [[base, base, base, ok, ok, hpt, hpt],
                              [base, base, base, -1, t48, -1, -1],       # E3: no row at flight 3
                              [base, base, off, back, ok, -1, -1]]
    every = fleet_grid(rows(), every=True)
    assert every[0] == ["E1", "E2", "E3", "E10"] and every[2][1].tolist() == [base] * 3 + [ok] * 4


def test_the_chart_draws_that_grid(figures, tmp_path):
    plot_fleet(rows(), tmp_path / "fleet.png")
    assert (tmp_path / "fleet.png").stat().st_size > 0
    ax = figures[0].axes[0]
    _, _, codes, _ = fleet_grid(rows())
    assert np.array_equal(ax.images[0].get_array(), codes + 1)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["baseline", "no fault", "not diagnosed", "recovery / bias gone", "hpt (step)",
                      "sensor:T48 (drift)"]
    bars = [ln.get_xdata()[0] for ln in ax.lines]
    assert bars == [4.5, 3.5]                      # E1's onset 5, E3's 4: the faults at their latest flights
    assert [t.get_text() for t in ax.get_yticklabels()] == ["E1", "E3", "E10"]
