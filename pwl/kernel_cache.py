"""Numba's on-disk cache of pwl's compiled kernels, kept in step with pwl's sources.

Numba checks a cached kernel against the file that defines it only. pwl's kernels call and
inline kernels of other files (the step loop's helpers are in ``interp.py``, ``grid.py``,
``tables.py``; streaming inlines ``runtime.py``'s step): after an update that changes a helper's
file alone (a ``git pull`` into the editable install the README sets up) numba would load a
kernel compiled with the old helper, with no error, and give numbers from the old code. So at
import a digest of the sources that define kernels (every ``.py`` of the package that uses
numba) is compared with the one the cache was made from; when they differ, pwl's cached kernels
are deleted (they recompile on first use, about a minute) and the new digest recorded.
"""
from __future__ import annotations

import glob
import hashlib
import os
import sys
import tempfile

STAMP = "pwl-sources.stamp"


def sources_stamp(package_dir: str) -> str:
    """A digest of the package's kernel sources: path and content of every .py file under
    ``package_dir`` that uses numba."""
    h = hashlib.sha1()
    for path in sorted(glob.glob(os.path.join(package_dir, "**", "*.py"), recursive=True)):
        with open(path, "rb") as f:
            text = f.read()
        if b"njit" in text:
            h.update(os.path.relpath(path, package_dir).encode() + b"\0" + text + b"\0")
    return h.hexdigest()


def _cache_folders(package_dir: str, cache_root: str | None) -> list[str]:
    """Where numba keeps the package's kernels: ``__pycache__`` beside the sources (its default),
    or, with a cache root (``NUMBA_CACHE_DIR``), one folder per source folder under it, named
    as numba names it."""
    folders = sorted({os.path.dirname(p) for p in glob.glob(os.path.join(package_dir, "**", "*.py"),
                                                             recursive=True)})
    if cache_root is None:
        return [os.path.join(f, "__pycache__") for f in folders]
    from numba.core.caching import _CacheLocator
    return [os.path.join(cache_root, _CacheLocator.get_suitable_cache_subpath(os.path.join(f, "x.py")))
            for f in folders]


def purge_stale_kernels(package_dir: str, cache_root: str | None = None) -> int:
    """Delete the package's cached kernels (``*.nbi``, ``*.nbc``) when its sources changed since
    they were cached; record the sources' stamp. Returns the number of files deleted (0 when
    the cache is current, or the cache folder is not writable: then numba does not write there
    either)."""
    stamp = sources_stamp(package_dir)
    base = os.path.join(package_dir, "__pycache__") if cache_root is None else cache_root
    stamp_file = os.path.join(base, STAMP if cache_root is None else
                              f"{STAMP}.{hashlib.sha1(os.path.abspath(package_dir).encode()).hexdigest()[:12]}")
    try:
        with open(stamp_file) as f:
            if f.read() == stamp:
                return 0
    except OSError:
        pass
    n = 0
    for folder in _cache_folders(package_dir, cache_root):
        for path in glob.glob(os.path.join(folder, "*.nb[ic]")):
            try:
                os.remove(path)
                n += 1
            except OSError:   # another process removed it first, or not ours to remove
                pass
    try:
        os.makedirs(base, exist_ok=True)
        tmp = f"{stamp_file}.{os.getpid()}"
        with open(tmp, "w") as f:
            f.write(stamp)
        os.replace(tmp, stamp_file)
    except OSError:
        pass
    return n


def _writable(folder: str) -> bool:
    """Whether a file can be created in ``folder`` (made if missing), as numba needs to cache."""
    try:
        os.makedirs(folder, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def cache_root(package_dir: str, writable=_writable) -> str | None:
    """Where numba should cache pwl's kernels: ``NUMBA_CACHE_DIR`` when set; None (numba's
    default, ``__pycache__`` beside the sources) when that is writable; else the first writable
    of the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``, ``pwl/numba``) and the
    temporary folder (``pwl-numba-<uid>``). An install the user cannot write to (site-packages
    of a system Python, a container run as another user) then compiles once per user instead of
    failing at import with numba's "cannot cache function ...: no locator available"."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    if writable(os.path.join(package_dir, "__pycache__")):
        return None
    user = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    for folder in (os.path.join(user, "pwl", "numba"), os.path.join(tempfile.gettempdir(), f"pwl-numba-{uid}")):
        if writable(folder):
            return folder
    return None


def check() -> int:
    """:func:`purge_stale_kernels` for pwl, in numba's cache folder for this process (set by
    :func:`cache_root`: ``NUMBA_CACHE_DIR`` and numba's config when pwl's own folder is not
    writable)."""
    package_dir = os.path.dirname(os.path.abspath(__file__))
    root = cache_root(package_dir)
    if root is not None and not os.environ.get("NUMBA_CACHE_DIR"):
        os.environ["NUMBA_CACHE_DIR"] = root
        if "numba" in sys.modules:        # numba read its config already: set it there too
            sys.modules["numba"].config.CACHE_DIR = root
    return purge_stale_kernels(package_dir, root)
