"""Health trending: snapshots, least-squares trends (vs numpy.polyfit), step and limit flags."""
import numpy as np
import pytest

from pwl.trending import snapshot, trend


def test_snapshot_ignores_transient_and_flagged_samples():
    t = np.arange(0, 200, 0.5)
    h = np.zeros((t.size, 2))
    h[:, 0] = -0.02
    h[t < 30, 0] = 5.0            # start-up transient
    flags = np.zeros(t.size, int)
    h[200:210, 1] = 9.0           # a flagged excursion
    flags[200:210] = 1
    s = snapshot(t, h, flags, ["a", "b"], settle=60.0)
    np.testing.assert_array_equal(s.values, [-0.02, 0.0])
    assert s.samples == np.count_nonzero((t >= 60) & (flags == 0))
    with pytest.raises(ValueError, match="no settled"):
        snapshot(t[:10], h[:10], flags[:10], ["a", "b"])


def make_snaps(values):
    return [snapshot(np.arange(100.0), np.tile(v, (100, 1)), np.zeros(100, int), ["a", "b"],
                     f"f{i}", settle=0) for i, v in enumerate(values)]


def test_trend_matches_polyfit_and_flags_a_step():
    rng = np.random.default_rng(0)
    m = 20
    x = np.arange(m)
    vals = np.column_stack([-0.0005 * x + rng.normal(0, 2e-4, m), 0.001 + rng.normal(0, 2e-4, m)])
    tr = trend(make_snaps(vals))
    for j in range(2):
        b, a = np.polyfit(x, vals[:, j], 1)
        assert tr.slope[j] == pytest.approx(b, rel=1e-10)
        assert tr.level[j] == pytest.approx(a + b * (m - 1), rel=1e-10)
    assert tr.flags == {}
    vals[-1, 1] -= 0.015                          # a sudden loss on b at the newest flight
    tr = trend(make_snaps(vals))
    assert list(tr.flags) == ["b"] and tr.flags["b"][0].startswith("step -0.01")
    vals[-1, 0] = -0.05                           # and a below-limit a
    tr = trend(make_snaps(vals), limit=-0.03)
    assert any(r.startswith("below") for r in tr.flags["a"])
    assert "parameter" in tr.table()
