"""The dependency direction of DESIGN.md and docs/architecture.md: the rooms and what each may import.

- pwl core (every module of ``pwl`` outside ``pwl.cli``, ``pwl.bench`` and ``pwl.fleet``) imports
  neither ``linearize``, ``models``, ``experiments``, ``pwl.fleet``, ``pwl.bench`` nor ``pwl.cli``,
  not even inside a function; importing it loads neither those nor ``control`` or ``matplotlib``
  (optional extras, imported inside the functions that need them; scipy is not checked: numba
  itself imports it when installed);
- ``pwl.fleet`` (runs of many logs, fleet diagnostics) imports pwl core and itself, no other
  first-party code; importing it loads neither ``matplotlib`` nor ``control``;
- ``models`` import neither ``pwl`` nor ``linearize`` (nor ``experiments``);
- nothing in ``pwl``, ``linearize`` or ``models`` imports ``experiments``, except the ``pwl``
  command's modules (``pwl.cli``), inside their functions only;
- ``experiments`` imports ``pwl``, ``linearize``, ``models`` and itself, no other first-party code.

Two checks: the imports written in the source (every ``import`` statement, at any depth, relative
ones resolved), and what importing the modules actually loads (``sys.modules``)."""
import ast
import os
import pkgutil
import subprocess
import sys

import experiments
import linearize
import models
import pwl

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIRST_PARTY = ("pwl", "linearize", "models", "experiments", "tests", "benchmarks")
NOT_CORE = ("pwl.cli", "pwl.bench", "pwl.fleet", "pwl.__main__")
#: what core imports never (the other rooms)
NOT_FOR_CORE = ("linearize", "models", "experiments", "pwl.fleet", "pwl.bench", "pwl.cli")


def _under(name: str, prefixes) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def core_modules():
    return sorted(m.name for m in pkgutil.walk_packages(pwl.__path__, "pwl.")
                  if not _under(m.name, NOT_CORE))


def package_modules(pkg):
    return sorted([pkg.__name__] + [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")])


def source_imports(modname: str):
    """(imported module, line, inside a function or class) of every import statement of a module;
    relative imports resolved; ``from a import b`` gives ``a.b`` (b may be a submodule)."""
    rel = modname.replace(".", os.sep)
    path = os.path.join(ROOT, rel, "__init__.py")
    is_pkg = os.path.exists(path)
    if not is_pkg:
        path = os.path.join(ROOT, rel + ".py")
    with open(path) as f:
        tree = ast.parse(f.read(), path)
    parent = modname if is_pkg else modname.rpartition(".")[0]
    out = []

    def visit(node, nested):
        for child in ast.iter_child_nodes(node):
            inner = nested or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
            if isinstance(child, ast.Import):
                out.extend((a.name, child.lineno, nested) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    up = parent.split(".")
                    up = up[:len(up) - (child.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                out.append((base, child.lineno, nested))
                out.extend((f"{base}.{a.name}", child.lineno, nested) for a in child.names)
            visit(child, inner)

    visit(tree, False)
    return out


def _violations(mods, forbidden, allow_nested=()):
    bad = []
    for m in mods:
        for name, line, nested in source_imports(m):
            if _under(name, forbidden) and not (nested and _under(name, allow_nested)):
                bad.append(f"{m}:{line} imports {name}{' (inside a function)' if nested else ''}")
    return bad


def test_core_imports_only_numpy_numba_h5py():
    mods = core_modules()
    assert "pwl.runtime" in mods and "pwl.database" in mods and "pwl.zones" in mods
    assert not any(_under(m, ("pwl.bench", "pwl.cli", "pwl.fleet")) for m in mods)
    code = ("import sys\n"
            + "".join(f"import {m}\n" for m in mods)
            + f"bad = [m for m in {NOT_FOR_CORE + ('control', 'matplotlib')!r} if m in sys.modules]\n"
            + "print(','.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"pwl core pulled in: {out.stdout.strip()}"


def test_core_source_imports_no_other_room():
    """Also the imports inside functions, which importing the modules does not run. (Optional
    extras may be imported inside a function: matplotlib for plots, python-control for
    ``GainDatabase.state_space``.)"""
    bad = _violations(core_modules(), NOT_FOR_CORE)
    assert not bad, "\n".join(bad)


def test_fleet_imports_core_only():
    """pwl.fleet sits on core: it imports core and itself, no other room (not even inside a
    function), and importing it loads neither the other rooms nor matplotlib or control."""
    mods = [m for m in package_modules(pwl) if _under(m, ("pwl.fleet",))]
    assert {"pwl.fleet.runs", "pwl.fleet.diagnose", "pwl.fleet.trending", "pwl.fleet.scoring",
            "pwl.fleet.signatures"} <= set(mods)
    bad = _violations(mods, ("linearize", "models", "experiments", "pwl.bench", "pwl.cli"))
    assert not bad, "\n".join(bad)
    # it does import core (so the test above can fail in the other direction)
    assert any(_under(name, ("pwl.database",)) for name, _, _ in source_imports("pwl.fleet.runs"))
    code = ("import sys\n" + "".join(f"import {m}\n" for m in mods)
            + "print(','.join(m for m in ('linearize', 'models', 'experiments', 'pwl.bench', 'pwl.cli', "
              "'control', 'matplotlib') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"pwl.fleet pulled in: {out.stdout.strip()}"


def test_models_import_neither_pwl_nor_linearize():
    mods = package_modules(models)[1:]
    code = ("import sys\n" + "".join(f"import {m}\n" for m in mods)
            + "print(','.join(m for m in ('pwl', 'linearize', 'experiments') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"models pulled in: {out.stdout.strip()}"


def test_only_the_command_imports_experiments_and_lazily():
    pwl_mods = package_modules(pwl)
    cli = [m for m in pwl_mods if _under(m, ("pwl.cli",))]
    assert "pwl.cli.zones" in cli and "pwl.bench.speed" in pwl_mods
    bad = _violations([m for m in pwl_mods if m not in cli], ("experiments",))
    bad += _violations(cli, ("experiments",), allow_nested=("experiments",))
    bad += _violations(package_modules(linearize) + package_modules(models), ("experiments",))
    assert not bad, "\n".join(bad)
    # the command does import them (so this test can fail)
    assert any(_under(name, ("experiments",)) for name, _, _ in source_imports("pwl.cli.zones"))


def test_experiments_import_pwl_linearize_models_only():
    mods = package_modules(experiments)
    assert {"experiments.ekf", "experiments.zones", "experiments.tables", "experiments.bias",
            "experiments.bias_observer", "experiments.biastable"} <= set(mods)
    allowed = ("pwl", "linearize", "models", "experiments")
    bad = [f"{m}:{line} imports {name}" for m in mods for name, line, _ in source_imports(m)
           if _under(name, FIRST_PARTY) and not _under(name, allowed)]
    assert not bad, "\n".join(bad)


def test_public_names_import_from_pwl_lazily():
    code = ("import sys, pwl\n"
            "light = 'pwl.estimator' not in sys.modules and 'pandas' not in sys.modules\n"
            "from pwl import *\n"
            "g = globals()\n"
            "missing = [n for n in pwl.__all__ if n not in g and n != '__version__']\n"
            "print(light, missing, pwl.Estimator.__module__, pwl.Stream.__module__)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "[]", "pwl.estimator", "pwl.streaming"]
