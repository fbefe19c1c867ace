"""Gain database: exact round trip, named errors for each kind of corruption, atomic save."""
import os

import h5py
import numpy as np
import pytest

from conftest import make_database
from pwl import database as dbm, formats
from pwl.h5io import USERBLOCK, seal
from pwl.database import GainDatabase


def assert_same(a, b):
    assert a.names == b.names and a.units == b.units
    assert a.trim_grid == b.trim_grid and a.dyn_grid == b.dyn_grid
    assert a.dt == b.dt and a.schedule == b.schedule
    for k in "xuyz":
        np.testing.assert_array_equal(a.trim[k], b.trim[k])
    for k in dbm.MATRICES:
        np.testing.assert_array_equal(a.dynamics[k], b.dynamics[k])
    for d1, d2 in ((a.tuner, b.tuner), (a.kalman, b.kalman)):
        assert d1.keys() == d2.keys()
        for k in d1:
            np.testing.assert_array_equal(d1[k], d2[k])
    for k in ("trim_status", "dyn_status", "dyn_donor", "kalman_status", "kalman_donor"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
        assert getattr(a, k).dtype.kind == getattr(b, k).dtype.kind
    if a.correction is None:
        assert b.correction is None
    else:
        c, d = a.correction, b.correction
        assert (c.theta_channel, c.delta_channel, c.T_std, c.P_std) == (
            d.theta_channel, d.delta_channel, d.T_std, d.P_std)
        for k in "xuyz":
            np.testing.assert_array_equal(c.exponents[k], d.exponents[k])
    assert {k: v for k, v in a.attrs.items() if k != "created"} == \
        {k: v for k, v in b.attrs.items() if k != "created"}
    for r1, r2 in [(a.zones, b.zones)] + [(a.tables[k], b.tables[k]) for k in a.tables]:
        assert r1[1] == r2[1] and r1[0].keys() == r2[0].keys()
        for k in r1[0]:
            np.testing.assert_array_equal(r1[0][k], r2[0][k])
    assert a.tables.keys() == b.tables.keys()


@pytest.mark.parametrize("kw", [{"filled": True}, {"correction": False, "policy": "extrapolate"},
                                {"nq": 0, "trim_shape": (2, 2), "dyn_shape": (2, 2)}])
def test_round_trip_is_exact(tmp_path, kw):
    db = make_database(**kw)
    p = tmp_path / "db.h5"
    db.save(p)
    back = GainDatabase.open(p)
    assert_same(db, back)
    back.save(tmp_path / "again.h5")  # and a second generation is identical too
    assert_same(db, GainDatabase.open(tmp_path / "again.h5"))


@pytest.fixture
def saved(tmp_path):
    p = tmp_path / "db.h5"
    make_database().save(p)
    return p


def edit(path, fn, reseal=True):
    """Change a saved database with h5py; ``reseal``: seal it again, as if pwl had written it so
    (what remains to catch is the content), else the seal no longer matches."""
    with h5py.File(path, "r+") as f:
        fn(f)
    if reseal:
        seal(path)


def test_not_hdf5(tmp_path):
    p = tmp_path / "notes.h5"
    p.write_text("hello")
    with pytest.raises(dbm.NotHDF5Error, match="notes.h5"):
        GainDatabase.open(p)


def test_missing_file(tmp_path):
    with pytest.raises(dbm.DatabaseError, match="no such file"):
        GainDatabase.open(tmp_path / "nope.h5")


def test_foreign_format(saved):
    edit(saved, lambda f: f.attrs.__setitem__("format", "something-else"))
    with pytest.raises(dbm.ForeignFormatError, match="something-else"):
        GainDatabase.open(saved)


def test_other_hdf5_file(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as f:
        f["data"] = np.arange(3)
    with pytest.raises(dbm.ForeignFormatError, match="other.h5"):
        GainDatabase.open(p)


def test_newer_version(saved):
    edit(saved, lambda f: f.attrs.__setitem__("format_version", dbm.VERSION + 1))
    with pytest.raises(dbm.VersionError, match="newer"):
        GainDatabase.open(saved)


@pytest.mark.parametrize("ds", ["kalman/K", "dynamics/L", "trim/y", "tuner/V_pinv", "names/q",
                                "trim/axes/p1", "dynamics/donor", "correction/u"])
def test_missing_dataset_is_named(saved, ds):
    edit(saved, lambda f: f.__delitem__(ds))
    with pytest.raises(dbm.MissingDataError, match=ds):
        GainDatabase.open(saved)


@pytest.mark.parametrize("ds", ["kalman/K", "dynamics/A", "trim/x", "tuner/V"])
def test_wrong_shape_is_named(saved, ds):
    def cut(f):
        a = f[ds][()]
        del f[ds]
        f[ds] = a[..., :-1] if a.shape[-1] > 1 else np.concatenate([a, a], axis=-1)
    edit(saved, cut)
    with pytest.raises(dbm.ShapeError, match=ds):
        GainDatabase.open(saved)


@pytest.mark.parametrize("bad, msg", [(np.nan, "not finite"), (-1.0, "not strictly increasing")])
def test_bad_axis_is_named(saved, bad, msg):
    def spoil(f):
        a = f["dynamics/axes/p1"][()]
        a[1] = bad
        f["dynamics/axes/p1"][...] = a
    edit(saved, spoil)
    with pytest.raises(dbm.BadAxisError, match=f"dynamics/axes/p1.*{msg}"):
        GainDatabase.open(saved)


def test_crash_during_save_leaves_no_partial_file(tmp_path, monkeypatch):
    p = tmp_path / "db.h5"
    good = make_database(seed=1)
    good.save(p)
    before = p.read_bytes()

    def boom(*a, **k):
        raise RuntimeError("disk on fire")
    monkeypatch.setattr(formats, "write_record", boom)  # fails after most datasets are written
    with pytest.raises(RuntimeError, match="disk on fire"):
        make_database(seed=2).save(p)
    assert p.read_bytes() == before                      # old file untouched
    assert sorted(os.listdir(tmp_path)) == ["db.h5"]      # no temporary left behind
    assert_same(good, GainDatabase.open(p))


def test_crash_of_first_save_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(formats, "write_record", lambda *a, **k: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        make_database().save(tmp_path / "db.h5")
    assert os.listdir(tmp_path) == []


def test_inconsistent_in_memory_database_is_rejected():
    db = make_database()
    db.kalman["K"] = db.kalman["K"][..., :1]
    with pytest.raises(dbm.ShapeError, match="kalman/K"):
        db.validate()


def test_info_command(saved, capsys):
    from pwl.cli import main
    assert main(["info", str(saved)]) == 0
    out = capsys.readouterr().out
    for s in (f"pwl-gain-database v{dbm.VERSION}", "sha256", "trim grid: 3 x 4", "p1", "filled", "replaced", "q (tuners, 2)"):
        assert s in out
    assert main(["info", str(saved) + ".missing"]) == 2


# ---- integrity: the seal, finite values, stable gains (#14) ------------------------------------
def test_any_change_after_writing_is_a_named_error(saved):
    clean = saved.read_bytes()
    rng = np.random.default_rng(0)
    for pos in rng.integers(USERBLOCK, len(clean), 20):       # single bit flips anywhere in the data
        b = bytearray(clean)
        b[pos] ^= 1 << int(rng.integers(8))
        saved.write_bytes(bytes(b))
        with pytest.raises(dbm.CorruptError, match="does not match its seal"):
            GainDatabase.open(saved)
    saved.write_bytes(clean[:len(clean) // 2])                  # truncated
    with pytest.raises(dbm.CorruptError, match="does not match its seal"):
        GainDatabase.open(saved)
    saved.write_bytes(clean)
    edit(saved, lambda f: f["kalman/K"].__setitem__((0, 0, 0, 0), 1.0), reseal=False)   # edited by h5py
    with pytest.raises(dbm.CorruptError, match="does not match its seal"):
        GainDatabase.open(saved)
    saved.write_bytes(bytes(USERBLOCK) + clean[USERBLOCK:])     # seal wiped: version 2 needs one
    with pytest.raises(dbm.CorruptError, match="seal is missing"):
        GainDatabase.open(saved)


def test_unsealed_version_1_files_still_open(saved):
    ref = GainDatabase.open(saved)
    edit(saved, lambda f: f.attrs.__setitem__("format_version", 1), reseal=False)
    with open(saved, "r+b") as fh:
        fh.write(bytes(USERBLOCK))                              # as written before seals existed
    db = GainDatabase.open(saved)
    assert db.format_version == 1 and not db.sealed and len(db.digest) == 64
    np.testing.assert_array_equal(db.kalman["K"], ref.kalman["K"])


@pytest.mark.parametrize("ds, value", [("kalman/K", np.nan), ("trim/y", np.inf), ("dynamics/A", -np.inf),
                                       ("tuner/h_ref", np.nan), ("kalman/R", np.nan)])
def test_non_finite_values_are_named(saved, ds, value):
    def spoil(f):
        a = f[ds][()]
        a.reshape(-1)[a.size // 2] = value
        f[ds][...] = a
    edit(saved, spoil)
    with pytest.raises(dbm.NonFiniteError, match=f"/{ds} has 1 non-finite values"):
        GainDatabase.open(saved)


@pytest.mark.parametrize("obj, attr, value", [("correction", "theta_channel", ""),
                                              ("correction", "delta_channel", "Tin"),
                                              ("correction", "T_std", -1.0)])
def test_corrupt_correction_attributes_are_named(saved, obj, attr, value):
    # an empty theta channel used to switch the parameter correction off without a word
    if GainDatabase.open(saved).correction is None:
        pytest.skip("this database has no correction")
    edit(saved, lambda f: f[obj].attrs.__setitem__(attr, value))
    with pytest.raises(dbm.DatabaseError, match="correction"):
        GainDatabase.open(saved)


def test_unstable_gain_is_named_with_its_node(saved):
    ref = GainDatabase.open(saved)
    # an independent check first: every stored gain is stable (numpy eigenvalues node by node)
    from pwl.runtime import augment
    aug = augment(ref.dynamics, ref.tuner["V_pinv"])
    for idx in np.ndindex(*ref.dyn_grid.shape):
        M = (np.eye(ref.na) - ref.kalman["K"][idx] @ aug["C"][idx]) @ aug["A"][idx]
        assert np.abs(np.linalg.eigvals(M)).max() == pytest.approx(ref.gain_radius()[idx], rel=1e-12)
    edit(saved, lambda f: f["kalman/K"].__setitem__((1, 2), -50 * f["kalman/K"][1, 2]))
    p1 = ref.dyn_grid.axes[1].values[2]
    with pytest.raises(dbm.UnstableGainError, match=f"at 1 nodes .*p1 = {p1:g}"):
        GainDatabase.open(saved)


def test_files_honour_the_umask(tmp_path):
    import os
    old = os.umask(0o027)
    try:
        make_database().save(tmp_path / "a.h5")
    finally:
        os.umask(old)
    assert (os.stat(tmp_path / "a.h5").st_mode & 0o777) == 0o640


def test_statespace_at_a_node_and_between_nodes():
    """python-control StateSpace of the model at an operating point: the stored matrices at a
    node, scipy's RegularGridInterpolator between nodes (independent of pwl's kernel)."""
    control = pytest.importorskip("control")
    from scipy.interpolate import RegularGridInterpolator

    db = make_database()
    dg = db.dyn_grid
    idx = (1, 2)
    node = {a.name: a.values[i] for a, i in zip(dg.axes, idx)}
    ss = db.statespace(node)
    assert isinstance(ss, control.StateSpace) and ss.dt == db.dt
    d = {k: db.dynamics[k][idx] for k in dbm.MATRICES}
    np.testing.assert_array_equal(ss.A, d["A"])
    np.testing.assert_array_equal(ss.B, np.hstack([d["B"], d["L"]]))
    np.testing.assert_array_equal(ss.C, np.vstack([d["C"], d["F"]]))
    np.testing.assert_array_equal(ss.D, np.block([[d["D"], d["M"]], [d["G"], d["N"]]]))
    assert ss.input_labels == db.names["u"] + db.names["h"]
    assert ss.output_labels == db.names["y"] + db.names["z"]
    p = [0.37 * dg.axes[0].hi, 0.61 * (dg.axes[1].lo + dg.axes[1].hi)]
    mid = db.statespace(p)
    rgi = RegularGridInterpolator([a.values for a in dg.axes], db.dynamics["A"])
    np.testing.assert_allclose(mid.A, rgi(p)[0], rtol=1e-12, atol=1e-14)
    with pytest.raises(dbm.DatabaseError, match="unknown scheduling variables"):
        db.statespace({"p0": 1.0, "bogus": 2.0})
    with pytest.raises(dbm.DatabaseError, match="2 scheduling variables"):
        db.statespace([1.0])
