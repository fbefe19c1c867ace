"""pwl.kernel_cache: a kernel cached by numba with a helper of another file is not loaded after
that helper's file changed (numba alone would load it: checked here first)."""
import os
import subprocess
import sys
import textwrap

import pytest

from pwl.kernel_cache import purge_stale_kernels, sources_stamp

HELPER = textwrap.dedent("""
    from numba import njit

    @njit(cache=True, inline="always")
    def helper():
        return {value}
""")
KERNEL = textwrap.dedent("""
    from numba import njit
    from .a import helper

    @njit(cache=True)
    def kernel():
        return helper()
""")
RUN = ("import sys; sys.path.insert(0, {root!r}); {guard}"
       "from pkg.b import kernel; print(kernel())")


def _package(root, value):
    pkg = root / "pkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(HELPER.format(value=value))
    (pkg / "b.py").write_text(KERNEL)
    return pkg


def _run(root, pkg, guard, env):
    g = f"from pwl.kernel_cache import purge_stale_kernels; purge_stale_kernels({str(pkg)!r}, " \
        f"{env.get('NUMBA_CACHE_DIR')!r}); " if guard else ""
    out = subprocess.run([sys.executable, "-c", RUN.format(root=str(root), guard=g)], env=env,
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@pytest.mark.parametrize("user_cache", [False, True])
def test_a_changed_helper_file_recompiles_the_kernel(tmp_path, user_cache):
    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)
    if user_cache:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    for guard in (False, True):
        root = tmp_path / ("guarded" if guard else "bare")
        root.mkdir()
        pkg = _package(root, 1)
        assert _run(root, pkg, guard, env) == 1
        assert _run(root, pkg, guard, env) == 1            # loaded from the cache
        _package(root, 2)                                  # the helper's file alone changes
        got = _run(root, pkg, guard, env)
        assert got == (2 if guard else 1), (guard, got)   # numba alone: the stale kernel


def test_stamp_follows_kernel_sources_only(tmp_path):
    pkg = _package(tmp_path, 1)
    s = sources_stamp(str(pkg))
    (pkg / "notes.py").write_text("x = 1\n")               # no kernel in it
    assert sources_stamp(str(pkg)) == s
    (pkg / "a.py").write_text(HELPER.format(value=3))
    assert sources_stamp(str(pkg)) != s
    cache = pkg / "__pycache__"
    cache.mkdir(exist_ok=True)
    (cache / "b.kernel-5.py311.nbi").write_text("")
    assert purge_stale_kernels(str(pkg)) == 1               # no stamp yet: purged
    (cache / "b.kernel-5.py311.nbi").write_text("")
    assert purge_stale_kernels(str(pkg)) == 0               # current: kept


def test_a_package_folder_the_user_cannot_write_caches_in_the_users_folder(tmp_path, monkeypatch):
    """A read-only install (another user's site-packages) caches in the user's cache folder, or
    the temporary folder, instead of failing at import ('no locator available'); NUMBA_CACHE_DIR
    wins; a writable install keeps numba's default."""
    from pwl.kernel_cache import cache_root
    pkg = str(tmp_path / "pkg")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_root(pkg) is None                                    # writable: numba's default
    ro = {os.path.join(pkg, "__pycache__")}
    assert cache_root(pkg, lambda f: f not in ro) == str(tmp_path / "xdg" / "pwl" / "numba")
    ro.add(str(tmp_path / "xdg" / "pwl" / "numba"))
    assert os.path.basename(cache_root(pkg, lambda f: f not in ro)).startswith("pwl-numba-")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert cache_root(pkg, lambda f: False) == str(tmp_path / "mine")


RECORD_KERNEL = textwrap.dedent("""
    import numpy as np
    from numba import njit
    from pwl.byref import fields, record

    Probe = record("CacheProbe", ["a", "b"], "a record passed to a cached kernel")

    @njit(cache=True, _nrt=False)      # fields() borrows: kernels reading them count no references
    def kernel(rec):
        a, b = fields(rec)
        return a[1] + b

    print(kernel(Probe(np.arange(3.0), 2.0)))
""")


def test_a_kernel_taking_a_record_is_loaded_from_the_cache(tmp_path):
    """A record's class and numba type are found again by name in a new process: the classes
    were made where pickle could not find them, numba pickled the kernel's signature by value,
    never matched it in the next process and compiled it again (a Stream took a minute to open in
    every process)."""
    (tmp_path / "rk.py").write_text(RECORD_KERNEL)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), NUMBA_DEBUG_CACHE="1")
    runs = [subprocess.run([sys.executable, "-c", "import rk"], cwd=tmp_path, env=env, capture_output=True,
                           text=True, check=True).stdout for _ in range(2)]
    assert all(r.strip().endswith("3.0") for r in runs), runs
    assert "data saved" in runs[0] and "rk.kernel" in runs[0]
    assert "data loaded" in runs[1] and "data saved" not in runs[1], runs[1]
