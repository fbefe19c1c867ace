"""Atomic HDF5 writing and small helpers shared by every file the project writes."""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile

import h5py
import numpy as np

STR = h5py.string_dtype("utf-8")


@contextlib.contextmanager
def atomic_h5(path, mode_attrs: dict | None = None, modify: bool = False):
    """Open a temporary HDF5 file beside ``path``; rename it onto ``path`` only on success.

    A crash or exception inside the block removes the temporary file and leaves any existing
    ``path`` untouched: no half-written files. ``modify``: start from a copy of an existing
    ``path`` (which must be HDF5) instead of an empty file.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    copy = modify and os.path.exists(path)
    if copy and not h5py.is_hdf5(path):
        raise OSError(f"{path}: exists and is not an HDF5 file; not touched")
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
    os.close(fd)
    try:
        if copy:
            shutil.copyfile(path, tmp)
        with h5py.File(tmp, "a" if copy else "w") as f:
            for k, v in (mode_attrs or {}).items():
                f.attrs[k] = v
            yield f
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise


def write_strings(group, name: str, values) -> None:
    """A 1-D UTF-8 string dataset."""
    group.create_dataset(name, data=np.array(list(values), dtype=object), dtype=STR)


def read_strings(dset) -> list[str]:
    return [s.decode() if isinstance(s, bytes) else str(s) for s in dset[()]]


def attr_str(obj, name: str, default=None):
    v = obj.attrs.get(name, default)
    return v.decode() if isinstance(v, bytes) else v
