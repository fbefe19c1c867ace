"""k-means gain zones (seed paper 001, Chen 2020): steady Kalman gains scheduled by clustering.

Offline, for a discrete-time plant x[k+1] = f(x, u) + w, y = h(x) + v:

1. N random operating points (u, x), uniform over a box (``plant.box_lo``/``box_hi`` or given);
2. Jacobians A = df/dx, C = dh/dx at each (analytic via ``plant.linearize(x, u)`` when the plant
   has it, else central finite differences of ``plant.evaluate``);
3. the steady update gain K at each with :func:`linearize.kalman.steady_state_gain` (the project's
   one gain formula); points where it fails are counted, excluded and reported;
4. k-means (Lloyd, k-means++ seeding, deterministic seed, best of ``n_init`` starts) on the gains,
   each gain element divided by its standard deviation over the points (``scale``), so that the
   elements weigh alike; zones are numbered by ascending centroid (lexicographic);
5. a lookup grid over the box: every node carries a zone label, either the label of the nearest
   sampled operating point in box-normalised coordinates (``label="nearest"``, default: the
   paper's zones are the clusters of the samples) or the zone whose centroid is nearest to the
   steady gain computed at the node itself (``label="gain"``: exact at the nodes, one DARE each).

The result is a :class:`pwl.zones.ZoneTable` (online form) whose ``record()`` is the ``/zones``
record of a gain database. :func:`database_zones` clusters the per-node gains of an existing
:class:`pwl.database.GainDatabase` instead (the lookup grid is then the dynamics grid).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from pwl.database import DatabaseError
from pwl.zones import ZoneTable
from pwl.grid import Axis, Grid

from .kalman import GainError, steady_state_gain
from .threads import one_blas_thread


# ---- plant side ---------------------------------------------------------------------------------
def jacobians(plant, x, u, rel_step: float = 1e-6):
    """(A (n, n), C (m, n)) of a discrete-time plant at (x, u): ``plant.linearize(x, u)`` when
    available, else central differences of ``plant.evaluate(x, u, h, env)`` (h = ``plant.h_ref``
    or None, env = None) with steps rel_step * max(1, |x_i|)."""
    x = np.asarray(x, dtype=np.float64)
    u = np.atleast_1d(np.asarray(u, dtype=np.float64))
    if hasattr(plant, "linearize"):
        A, C = plant.linearize(x, u)
        return np.asarray(A, dtype=np.float64), np.atleast_2d(np.asarray(C, dtype=np.float64))
    return fd_jacobians(plant, x, u, rel_step)


def fd_jacobians(plant, x, u, rel_step: float = 1e-6):
    """Central finite-difference (A, C) of ``plant.evaluate`` at (x, u) (discrete plants)."""
    if getattr(plant, "time", "discrete") != "discrete":
        raise ValueError(f"{getattr(plant, 'name', 'plant')}: gain zones need a discrete-time plant "
                         "(evaluate must return x[k+1]); got time = 'continuous'")
    x = np.asarray(x, dtype=np.float64)
    u = np.atleast_1d(np.asarray(u, dtype=np.float64))
    href = getattr(plant, "h_ref", None)
    n = x.size
    f0, y0, _ = plant.evaluate(x, u, href, None)
    A = np.empty((n, np.size(f0)))
    C = np.empty((np.size(y0), n))
    for i in range(n):
        d = rel_step * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += d
        xm[i] -= d
        fp, yp, _ = plant.evaluate(xp, u, href, None)
        fm, ym, _ = plant.evaluate(xm, u, href, None)
        A[:, i] = (np.asarray(fp) - np.asarray(fm)) / (2 * d)
        C[:, i] = (np.asarray(yp) - np.asarray(ym)) / (2 * d)
    return A, C


@dataclass
class Samples:
    """Random operating points and their steady gains (failures excluded).

    ``points`` (N_ok, nu + nx) in (u, x) order; ``gains`` (N_ok, n, m); ``lo``/``hi`` the box;
    ``names``/``units`` of the coordinates; ``failed`` how many points had no gain and
    ``failures`` the first few (index, message) pairs.
    """

    points: np.ndarray
    gains: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    names: tuple
    units: tuple
    n_total: int
    failed: int
    failures: list
    seed: int
    model: str = ""


@one_blas_thread
def sample_gains(plant, N: int = 10_000, seed: int = 0, lo=None, hi=None, Q=None, R=None,
                 keep_failures: int = 10) -> Samples:
    """N uniform random operating points (u, x) in the box [lo, hi] and the steady gain at each
    (filter covariances ``plant.Q``/``plant.R`` unless given)."""
    nu, nx = len(plant.u_names), len(plant.x_names)
    lo = np.asarray(plant.box_lo if lo is None else lo, dtype=np.float64)
    hi = np.asarray(plant.box_hi if hi is None else hi, dtype=np.float64)
    if lo.shape != (nu + nx,) or hi.shape != lo.shape or not np.all(hi > lo):
        raise ValueError(f"box must be (lo, hi) with {nu + nx} coordinates (u, x) and hi > lo; "
                         f"got {lo}, {hi}")
    if N < 1:
        raise ValueError(f"N must be positive, got {N}")
    Q = np.asarray(plant.Q if Q is None else Q, dtype=np.float64)
    R = np.asarray(plant.R if R is None else R, dtype=np.float64)
    rng = np.random.default_rng(seed)
    pts = lo + (hi - lo) * rng.random((N, nu + nx))
    gains, ok, failures = [], np.zeros(N, bool), []
    for i in range(N):
        u, x = pts[i, :nu], pts[i, nu:]
        try:
            A, C = jacobians(plant, x, u)
            K, _ = steady_state_gain(A, C, Q, R)
        except (GainError, np.linalg.LinAlgError, ValueError, FloatingPointError) as e:
            if len(failures) < keep_failures:
                failures.append((i, f"operating point u={u.tolist()}, x={x.tolist()}: {e}"))
            continue
        ok[i] = True
        gains.append(K)
    names = tuple(plant.u_names) + tuple(plant.x_names)
    units = getattr(plant, "units", {})
    if not ok.any():
        raise GainError(f"{getattr(plant, 'name', 'plant')}: no steady gain at any of {N} "
                        f"operating points; first failure: {failures[0][1] if failures else '?'}")
    return Samples(pts[ok], np.array(gains), lo, hi, names, tuple(units.get(n, "") for n in names),
                   N, int(N - ok.sum()), failures, int(seed), getattr(plant, "name", ""))


# ---- k-means ------------------------------------------------------------------------------------
def _sqdist(X, C):
    return (X * X).sum(1)[:, None] - 2.0 * X @ C.T + (C * C).sum(1)[None, :]


def kmeans(X, k: int, seed: int = 0, n_init: int = 10, max_iter: int = 300):
    """Lloyd's k-means with k-means++ seeding; best (lowest distortion) of ``n_init`` starts.

    Deterministic for a given seed. Returns (centers (k, d), labels (N,), distortion = mean
    squared distance to the own centre). Clusters are numbered by ascending centre
    (lexicographic). An empty cluster is re-seeded at the point farthest from its centre.
    """
    X = np.asarray(X, dtype=np.float64)
    N = X.shape[0]
    if not 1 <= k <= N:
        raise ValueError(f"k must be in 1..{N} (the number of points), got {k}")
    rng = np.random.default_rng(seed)
    best = None
    for _ in range(n_init):
        C = np.empty((k, X.shape[1]))
        C[0] = X[rng.integers(N)]
        d2 = ((X - C[0]) ** 2).sum(1)
        for j in range(1, k):
            tot = d2.sum()
            i = rng.choice(N, p=d2 / tot) if tot > 0 else rng.integers(N)
            C[j] = X[i]
            d2 = np.minimum(d2, ((X - C[j]) ** 2).sum(1))
        labels = None
        for _it in range(max_iter):
            D = _sqdist(X, C)
            new = D.argmin(1)
            if labels is not None and np.array_equal(new, labels):
                break
            labels = new
            for j in range(k):
                mask = labels == j
                if mask.any():
                    C[j] = X[mask].mean(0)
                else:
                    far = int(D[np.arange(N), labels].argmax())
                    C[j] = X[far]
                    labels[far] = j
        dist = float(np.maximum(_sqdist(X, C)[np.arange(N), labels], 0.0).mean())
        if best is None or dist < best[2] - 1e-15 * max(1.0, best[2]):
            best = (C.copy(), labels.copy(), dist)
    C, labels, dist = best
    order = np.lexsort(C.T[::-1])
    remap = np.empty(k, dtype=np.int64)
    remap[order] = np.arange(k)
    return C[order], remap[labels], dist


def gain_scale(G):
    """Per-element scale of flattened gains G (N, n*m): the standard deviation over the points;
    elements that do not vary use their mean magnitude (or 1 when zero)."""
    s = G.std(0)
    fallback = np.abs(G).mean(0)
    s = np.where(s > 1e-12 * np.maximum(fallback, 1e-300), s, np.where(fallback > 0, fallback, 1.0))
    return s


# ---- zones ----------------------------------------------------------------------------------------
@dataclass
class ZoneBuild:
    """A zone table plus the offline data it came from (for figures and checks)."""

    table: ZoneTable
    samples: Samples
    labels: np.ndarray       # (N_ok,) zone of each sampled operating point
    distortion: float        # k-means mean squared distance (normalised gain space)


def lookup_grid(lo, hi, names, units, shape) -> Grid:
    """Uniform grid over the box, ``shape`` an int (every axis) or one int per axis (>= 2)."""
    d = len(names)
    shape = (int(shape),) * d if np.isscalar(shape) else tuple(int(s) for s in shape)
    if len(shape) != d or min(shape) < 2:
        raise ValueError(f"lookup shape needs {d} entries >= 2, got {shape}")
    return Grid([Axis(nm, np.linspace(lo[j], hi[j], shape[j]), un)
                 for j, (nm, un, _) in enumerate(zip(names, units, shape))])


def make_zones(samples: Samples, k: int = 3, seed: int = 0, lookup_shape=41, label: str = "nearest",
               plant=None, Q=None, R=None, n_init: int = 10) -> ZoneBuild:
    """Cluster the sampled gains into k zones and label a lookup grid (see the module doc).
    ``label="gain"`` needs the ``plant`` (and uses its Q, R unless given)."""
    if label not in ("nearest", "gain"):
        raise ValueError(f"label must be 'nearest' or 'gain', got {label!r}")
    G = samples.gains.reshape(samples.gains.shape[0], -1)
    scale = gain_scale(G)
    centers, labels, dist = kmeans(G / scale, k, seed, n_init=n_init)
    gains = (centers * scale).reshape((k,) + samples.gains.shape[1:])
    grid = lookup_grid(samples.lo, samples.hi, samples.names, samples.units, lookup_shape)
    nodes = grid.nodes()
    node_labels = nearest_sample_labels(samples, labels, nodes)
    n_gain_fail = 0
    if label == "gain":
        if plant is None:
            raise ValueError("label='gain' needs the plant")
        Qm = np.asarray(plant.Q if Q is None else Q, dtype=np.float64)
        Rm = np.asarray(plant.R if R is None else R, dtype=np.float64)
        nu = len(plant.u_names)
        for r, pt in enumerate(nodes):
            try:
                A, C = jacobians(plant, pt[nu:], pt[:nu])
                Kn, _ = steady_state_gain(A, C, Qm, Rm)
            except (GainError, np.linalg.LinAlgError, ValueError):
                n_gain_fail += 1       # keeps the nearest-sample label
                continue
            node_labels[r] = int(_sqdist(Kn.reshape(1, -1) / scale, centers)[0].argmin())
    attrs = {"source": "operating points", "model": samples.model, "N": int(samples.n_total),
             "N_used": int(samples.points.shape[0]), "failed": int(samples.failed),
             "failures": [f"{i}: {m}" for i, m in samples.failures], "sample_seed": samples.seed,
             "kmeans_seed": int(seed), "kmeans_n_init": int(n_init), "distortion": dist,
             "scale_method": "std over points", "label_method": label,
             "label_gain_failures": int(n_gain_fail), "box_lo": samples.lo.tolist(),
             "box_hi": samples.hi.tolist(), "coordinates": "(u, x)"}
    table = ZoneTable(gains=gains, grid=grid, labels=node_labels.reshape(grid.shape),
                      centers=centers, scale=scale, counts=np.bincount(labels, minlength=k),
                      attrs=attrs)
    return ZoneBuild(table, samples, labels, dist)


def nearest_sample_labels(samples: Samples, labels, points) -> np.ndarray:
    """Label of the nearest sampled operating point (box-normalised Euclidean distance) for every
    row of ``points`` (k-d tree, offline)."""
    from scipy.spatial import cKDTree

    w = samples.hi - samples.lo
    tree = cKDTree((samples.points - samples.lo) / w)
    _, i = tree.query((np.asarray(points, dtype=np.float64) - samples.lo) / w)
    return np.asarray(labels, dtype=np.int64)[i]


def build_zones(plant, k: int = 3, N: int = 10_000, seed: int = 0, lookup_shape=41,
                label: str = "nearest", lo=None, hi=None, Q=None, R=None) -> ZoneBuild:
    """Sample, compute gains, cluster and label: the whole offline step for an operating-point
    plant (``seed`` seeds the sampling and k-means)."""
    s = sample_gains(plant, N, seed, lo, hi, Q, R)
    return make_zones(s, k, seed, lookup_shape, label, plant, Q, R)


# ---- zones of a gain database ---------------------------------------------------------------------
def database_zones(db, k: int = 3, seed: int = 0, n_init: int = 10):
    """Cluster the update gains K of a :class:`pwl.database.GainDatabase` over its dynamics grid.

    Each gain element is divided by its standard deviation over the nodes before k-means. Returns
    ``(record, zoned)``: the ``/zones`` record (lookup grid = the dynamics grid, one label per
    node) and a deep copy of the database whose K at every node is its zone's centroid gain
    (its ``zones`` set to the record; P, Q, R untouched). The record's attrs hold the
    within-zone gain error (relative Frobenius norm |K - K_zone| / |K|: max, mean) and the bytes
    of K against the bytes of the record.
    """
    K = np.asarray(db.kalman["K"], dtype=np.float64)
    D = db.dyn_grid.shape
    shp = K.shape[len(D):]
    G = K.reshape(-1, int(np.prod(shp)))
    if not np.all(np.isfinite(G)):
        raise GainError(f"{db.path}: non-finite gains in /kalman/K; cannot cluster")
    if k > G.shape[0]:
        raise ValueError(f"k = {k} exceeds the {G.shape[0]} dynamics nodes of {db.path}")
    scale = gain_scale(G)
    centers, labels, dist = kmeans(G / scale, k, seed, n_init=n_init)
    gains = (centers * scale).reshape((k,) + shp)
    Kz = gains[labels].reshape(K.shape)
    rel = np.linalg.norm((G - Kz.reshape(G.shape)), axis=1) / np.maximum(np.linalg.norm(G, axis=1), 1e-300)
    grid = Grid(db.dyn_grid.axes)
    table = ZoneTable(gains=gains, grid=grid, labels=labels.reshape(D), centers=centers, scale=scale,
                      counts=np.bincount(labels, minlength=k),
                      attrs={"source": "database", "model": db.attrs.get("model", ""),
                             "N": int(G.shape[0]), "N_used": int(G.shape[0]), "failed": 0,
                             "kmeans_seed": int(seed), "kmeans_n_init": int(n_init),
                             "distortion": dist, "scale_method": "std over nodes",
                             "label_method": "node", "coordinates": "dynamics grid",
                             "gain_rel_error_max": float(rel.max()),
                             "gain_rel_error_mean": float(rel.mean()),
                             "K_bytes": int(K.nbytes)})
    table.attrs["record_bytes"] = table.nbytes()
    record = table.record()
    zoned = copy.deepcopy(db)
    zoned.kalman["K"] = np.ascontiguousarray(Kz)
    zoned.zones = record
    zoned.attrs = dict(zoned.attrs, gains="k-means zone centroids", zones_k=int(k))
    try:
        zoned.check_gains()
    except DatabaseError as e:
        raise GainError(f"the k = {k} zone gains are not stabilizing everywhere: {e}; use more "
                        f"zones") from None
    return record, zoned


# ---- storage ---------------------------------------------------------------------------------------
def attach(db, table: ZoneTable) -> None:
    """Put the zones into a gain database (``db.zones``; written by ``db.save`` through
    :func:`pwl.zones.write_zones`, the one zones writer; a stand-alone zones file:
    :func:`pwl.zones.save_zones`)."""
    db.zones = table.record()

