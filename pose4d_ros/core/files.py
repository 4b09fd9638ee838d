"""Files written whole or not at all: to a temporary name beside the target, then renamed;
and the model files' .npz archives (a JSON header and named arrays), read with one clear error."""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

# What numpy raises on a damaged or foreign .npz (a zip error, a bad member, a short file)
NPZ_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)

_UMASK = os.umask(0o022)  # read once, at import (setting it is process-wide)
os.umask(_UMASK)


def write_atomic(path: str | Path, data: bytes) -> None:
    """Write `data` to `path` through a temporary file in the same directory and a rename, so a
    reader never sees a half-written file and a failure leaves none behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'wb') as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_UMASK)  # as open() would create it (mkstemp gives 0600)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: str | Path, obj: Any, *, indent: int = 2,
               default: Callable[[Any], Any] | None = None) -> None:
    """`obj` as JSON (with a final newline), written atomically (`write_atomic`)."""
    write_atomic(path, (json.dumps(obj, indent=indent, default=default) + '\n').encode())


def write_npz(path: str | Path, header: Mapping[str, Any], arrays: Mapping[str, Any]) -> None:
    """`header` (as JSON, the array 'header') and `arrays` as one compressed .npz, written
    atomically (`write_atomic`)."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, header=np.array(json.dumps(header)), **arrays)
    write_atomic(path, buffer.getvalue())


def read_npz(path: str | Path, what: str) -> dict[str, np.ndarray]:
    """Every array of the .npz at `path`; OSError when there is no such file, ValueError naming
    the file and `what` it should be when it is damaged or no .npz."""
    path = Path(path)
    if not path.is_file():
        raise OSError(f'{path}: no such model file')
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except NPZ_ERRORS as exc:
        raise ValueError(f'{path}: not a {what}: damaged or not a NumPy .npz archive '
                         f'({type(exc).__name__}: {exc})') from exc


def replace_dir(tmp: Path, out: Path) -> None:
    """Move the finished directory `tmp` to `out` (replacing an old one only once the new one
    is in place, so a reader never finds `out` half-written)."""
    if out.exists():
        trash = Path(tempfile.mkdtemp(prefix=f'.{out.name}.', suffix='.old', dir=out.parent))
        trash.rmdir()
        out.rename(trash)
        tmp.rename(out)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        tmp.rename(out)
