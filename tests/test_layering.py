"""The dependency direction of DESIGN.md: pwl core never imports linearize, models, control or
matplotlib (scipy is not checked: numba itself imports it when installed)."""
import pkgutil
import subprocess
import sys

import pwl


def core_modules():
    return sorted(m.name for m in pkgutil.walk_packages(pwl.__path__, "pwl.")
                  if not m.name.startswith(("pwl.cli", "pwl.bench", "pwl.reference", "pwl.__main__")))


def test_core_imports_only_numpy_numba_h5py():
    mods = core_modules()
    assert "pwl.runtime" in mods and "pwl.database" in mods
    code = ("import sys\n"
            + "".join(f"import {m}\n" for m in mods)
            + "bad = [m for m in ('linearize', 'models', 'control', 'matplotlib') if m in sys.modules]\n"
            + "print(','.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"pwl core pulled in: {out.stdout.strip()}"


def test_models_import_neither_pwl_nor_linearize():
    import models
    mods = sorted(m.name for m in pkgutil.walk_packages(models.__path__, "models."))
    code = ("import sys\n" + "".join(f"import {m}\n" for m in mods)
            + "print(','.join(m for m in ('pwl', 'linearize') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"models pulled in: {out.stdout.strip()}"


def test_public_names_import_from_pwl_lazily():
    code = ("import sys, pwl\n"
            "light = 'pwl.estimator' not in sys.modules and 'pandas' not in sys.modules\n"
            "from pwl import *\n"
            "g = globals()\n"
            "missing = [n for n in pwl.__all__ if n not in g and n != '__version__']\n"
            "print(light, missing, pwl.Estimator.__module__, pwl.Stream.__module__)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "[]", "pwl.estimator", "pwl.streaming"]
