"""Atomic, sealed HDF5 writing and small helpers shared by every file the project writes.

Every HDF5 file pwl writes starts with a 512-byte HDF5 user block (bytes HDF5 itself ignores)
holding a seal: ``pwl-seal sha256 <64 hex digits>`` of every byte after the user block. Readers
check the seal before HDF5 parses anything (:func:`check_seal`), so a flipped byte or a truncated
file is a named error in milliseconds, never a hang or garbage from inside the HDF5 library; the
digest is also the file's identity in provenance records.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile

import h5py
import numpy as np

from .errors import PwlError

STR = h5py.string_dtype("utf-8")
USERBLOCK = 512
SEAL = b"pwl-seal sha256 "
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


class SealError(PwlError, ValueError):
    """A sealed file whose content no longer matches its seal (corrupted, truncated or edited)."""


def _digest(path, start: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        f.seek(start)
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def seal(path) -> str:
    """Write the seal of ``path`` (an HDF5 file with a 512-byte user block) into its user block;
    returns the digest."""
    with open(path, "rb") as f:
        head = f.read(USERBLOCK + len(HDF5_SIGNATURE))
    if head[USERBLOCK:] != HDF5_SIGNATURE:
        raise SealError(f"{path}: has no {USERBLOCK}-byte HDF5 user block to hold a seal")
    digest = _digest(path, USERBLOCK)
    with open(path, "r+b") as f:
        f.write((SEAL + digest.encode() + b"\n").ljust(USERBLOCK, b"\0"))
    return digest


def check_seal(path) -> str | None:
    """The digest of a sealed file after checking it; None for a file without a seal (written by
    another tool or an older pwl). Raises :class:`SealError` naming the file when the content does
    not match the seal."""
    path = os.fspath(path)
    with open(path, "rb") as f:
        head = f.read(USERBLOCK)
    if not head.startswith(SEAL):
        return None
    stored = head[len(SEAL):len(SEAL) + 64].decode("ascii", "replace")
    actual = _digest(path, USERBLOCK)
    if stored != actual or head[len(SEAL) + 64:len(SEAL) + 65] != b"\n":
        raise SealError(f"{path}: content does not match its seal (the file is corrupted, truncated "
                        f"or was edited outside pwl); restore it or write it again")
    return actual


def file_digest(path) -> str:
    """The file's identity: its seal's digest, or the sha256 of the whole file when unsealed."""
    return check_seal(path) or _digest(path, 0)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_h5(path, mode_attrs: dict | None = None, modify: bool = False):
    """Open a temporary HDF5 file beside ``path``; seal it and rename it onto ``path`` only on
    success (permissions as the umask allows, like any new file).

    A crash or exception inside the block removes the temporary file and leaves any existing
    ``path`` untouched: no half-written files. ``modify``: start from a copy of an existing
    ``path`` (which must be HDF5, and match its seal if it has one) instead of an empty file; a
    file without a user block (an older pwl's) stays unsealed.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    copy = modify and os.path.exists(path)
    if copy and not h5py.is_hdf5(path):
        raise OSError(f"{path}: exists and is not an HDF5 file; not touched")
    if copy:
        check_seal(path)   # never re-seal (launder) a corrupted file
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
    os.close(fd)
    try:
        if copy:
            shutil.copyfile(path, tmp)
            f = h5py.File(tmp, "a")
        else:
            f = h5py.File(tmp, "w", userblock_size=USERBLOCK)
        with f:
            for k, v in (mode_attrs or {}).items():
                f.attrs[k] = v
            yield f
            sealable = f.userblock_size == USERBLOCK
        if sealable:
            seal(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise


def write_strings(group, name: str, values) -> None:
    """A 1-D UTF-8 string dataset."""
    group.create_dataset(name, data=np.array(list(values), dtype=object), dtype=STR)


def as_strings(values) -> list[str]:
    """HDF5 strings (bytes or str, any shape: a dataset's or an attribute's values) as a flat list of str."""
    return [s.decode() if isinstance(s, bytes) else str(s) for s in np.ravel(values)]


def read_strings(dset) -> list[str]:
    return as_strings(dset[()])


def attr_str(obj, name: str, default=None):
    """HDF5 attribute ``name`` of ``obj`` (a file, group or dataset) as a plain value: text as str
    (not bytes), numbers as Python's, and a 1-element array as its element (tools that store every
    attribute as an array: MATLAB's h5writeatt, ``attrs["unit"] = np.array([b"K"])``)."""
    v = obj.attrs.get(name, default)
    if isinstance(v, np.ndarray) and v.size == 1:
        v = v.reshape(-1)[0]
    if isinstance(v, np.generic):
        v = v.item()
    return v.decode() if isinstance(v, bytes) else v
