"""Grid search and the interpolation kernel against scipy's RegularGridInterpolator."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.interpolate import RegularGridInterpolator

from pwl.grid import Axis, AxisError, Grid, find_interval, locate
from pwl.interp import interpolate


def random_grid(rng, ndim, policy="clip"):
    axes = []
    for j in range(ndim):
        n = int(rng.integers(2, 6))
        v = np.cumsum(rng.uniform(0.05, 2.0, n)) - rng.uniform(-5, 5)
        axes.append(Axis(f"a{j}", v))
    return Grid(axes, policy)


def rgi(grid, values, points):
    f = RegularGridInterpolator([a.values for a in grid.axes], values, method="linear",
                                bounds_error=False, fill_value=None)
    return f(points)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), ndim=st.integers(1, 5), block=st.integers(1, 7))
def test_matches_rgi_inside(seed, ndim, block):
    rng = np.random.default_rng(seed)
    g = random_grid(rng, ndim)
    values = rng.normal(size=g.shape + (block,)) * 10 ** rng.uniform(-3, 3)
    lo = np.array([a.lo for a in g.axes])
    hi = np.array([a.hi for a in g.axes])
    pts = lo + rng.random((50, ndim)) * (hi - lo)
    pts[:5] = g.nodes()[rng.integers(0, g.size, 5)]  # exactly on nodes too
    got = interpolate(g, values, pts)
    ref = rgi(g, values, pts)
    scale = np.abs(values).max()
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * scale)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), ndim=st.integers(1, 5))
def test_clip_equals_rgi_at_clipped_point_and_extrapolate_equals_rgi(seed, ndim):
    rng = np.random.default_rng(seed)
    g = random_grid(rng, ndim)
    values = rng.normal(size=g.shape + (3,))
    lo = np.array([a.lo for a in g.axes])
    hi = np.array([a.hi for a in g.axes])
    pts = lo + rng.uniform(-0.5, 1.5, (40, ndim)) * (hi - lo)
    np.testing.assert_allclose(interpolate(g, values, pts), rgi(g, values, np.clip(pts, lo, hi)),
                               rtol=1e-12, atol=1e-12)
    ge = Grid(g.axes, "extrapolate")
    # RGI with fill_value=None extrapolates linearly from the edge cells, as our policy does
    np.testing.assert_allclose(interpolate(ge, values, pts), rgi(g, values, pts), rtol=1e-10, atol=1e-10)


def test_flags_name_the_clipped_axes():
    g = Grid([Axis("a", [0, 1, 2]), Axis("b", [0, 1])])
    _, frac, flags = g.locate([3.0, 0.5])
    assert flags == 0b01 and frac[0] == 1.0
    _, _, flags = g.locate([1.0, -1.0])
    assert flags == 0b10
    _, _, flags = g.locate([1.0, 0.5])
    assert flags == 0


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_hint_does_not_change_the_result(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 30))
    bp = np.cumsum(rng.uniform(0.01, 1.0, n))
    # random walk with occasional jumps, plus exact breakpoints
    x = bp[0] + np.cumsum(rng.normal(0, 0.05, 300))
    jumps = rng.random(300) < 0.1
    x[jumps] = rng.uniform(bp[0], bp[-1], jumps.sum())
    x = np.clip(x, bp[0], bp[-1])
    x[::37] = bp[rng.integers(0, n, x[::37].size)]
    hint = 0
    for xi in x:
        fresh = find_interval(bp, 0, n, xi, -1)
        hinted = find_interval(bp, 0, n, xi, hint)
        assert bp[hinted] <= xi <= bp[hinted + 1]
        # the same cell, or the neighbouring one when xi sits exactly on their shared breakpoint
        assert hinted == fresh or (xi == bp[max(hinted, fresh)])
        hint = hinted
        for h in rng.integers(-2, n + 2, 3):  # arbitrary (also invalid) hints
            assert bp[find_interval(bp, 0, n, xi, h)] <= xi <= bp[find_interval(bp, 0, n, xi, h) + 1]


def test_locate_with_hint_gives_same_weights_as_fresh():
    rng = np.random.default_rng(1)
    g = random_grid(rng, 3)
    idx_h, frac_h = g.workspace()
    lo = np.array([a.lo for a in g.axes])
    hi = np.array([a.hi for a in g.axes])
    p = lo + 0.5 * (hi - lo)
    for _ in range(500):
        p = np.clip(p + rng.normal(0, 0.05, 3) * (hi - lo), lo, hi)
        if rng.random() < 0.05:
            p = lo + rng.random(3) * (hi - lo)
        locate(g.bp, g.off, p, False, idx_h, frac_h)
        idx_f, frac_f = g.workspace()
        idx_f[:] = -1
        locate(g.bp, g.off, p, False, idx_f, frac_f)
        # equal points in the cell: same interpolation weights even if a tie picked another cell
        np.testing.assert_allclose(idx_h + frac_h, idx_f + frac_f, atol=1e-15)


@pytest.mark.parametrize("values, msg", [
    ([1.0], "at least 2"),
    ([0.0, np.nan, 2.0], "not finite"),
    ([0.0, 2.0, 1.0], "not strictly increasing"),
    ([0.0, 1.0, 1.0], "not strictly increasing"),
    ([[0.0, 1.0]], "1-D"),
])
def test_bad_axes_are_named(values, msg):
    with pytest.raises(AxisError, match=msg) as e:
        Axis("Mach", values)
    assert "Mach" in str(e.value)


def test_grid_rejects_bad_policy_and_dims():
    with pytest.raises(ValueError, match="policy"):
        Grid([Axis("a", [0, 1])], "wrap")
    with pytest.raises(AxisError):
        Grid([Axis(f"a{i}", [0, 1]) for i in range(7)])
    with pytest.raises(AxisError, match="duplicate"):
        Grid([Axis("a", [0, 1]), Axis("a", [0, 2])])
