"""Where the shipped demo data are: the demo gain database and the two sample flight logs in the
repository's ``data/`` folder (used by ``pwl demo``, the benchmarks and the tests)."""
from __future__ import annotations

import os


def demo_paths():
    """The shipped demo database and sample logs (in the repository's data/ folder)."""
    data = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")
    return (os.path.join(data, "turbofan_demo.h5"),
            [os.path.join(data, f"flight_{k}.h5") for k in ("new", "degraded")])
