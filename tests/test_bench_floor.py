"""The speed floor of ``pwl bench run`` (pwl.bench.floor) computes the filter's estimates: its
ratio to the runtime means something only if it does the same work."""
import numpy as np

from pwl.bench.floor import flops_per_step, make_floor
from pwl.bench.reference import ReferenceFilter
from pwl.estimator import Estimator
from test_runtime import inputs, names_db


def test_floor_loop_equals_the_reference_filter():
    db = names_db()
    est = Estimator(db)
    U, Y, S, TH, DE = inputs(db, n=300)
    ref = ReferenceFilter(db).run(U, Y, S, TH, DE)
    m, g = est._model, est._grids
    out = {o: np.empty_like(ref[o]) for o in ("x_hat", "q_hat", "y_hat", "residual", "z_hat")}
    make_floor(m.dims, S.shape[1])(U, Y, S, TH, DE, m.trim_tab, m.dyn_tab, m.ex, m.cls, m.s_scale,
                                  m.s_corr, m.amb_col, m.amb_p, m.amb_k, g.t_bp, g.t_off, g.t_str,
                                  g.t_pidx, g.d_bp, g.d_off, g.d_str, g.d_pidx, np.full(int(m.dims[0]), np.nan),
                                  np.zeros(int(m.dims[4])), *out.values())
    for o, v in out.items():
        np.testing.assert_allclose(v, ref[o], rtol=1e-10, atol=1e-10 * np.abs(ref[o]).max(), err_msg=o)
    nx, nu, ny, nz, nq = (int(d) for d in m.dims[:5])
    corners = 2 * (4 * m.trim_tab.shape[1] + 4 * m.dyn_tab.shape[1])     # two 2-D grids
    assert flops_per_step(m, g) == corners + 2 * ((nx + ny + nz) * (nx + nq + nu) + (nx + nq) * ny)
