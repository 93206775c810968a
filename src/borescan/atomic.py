"""Atomic file and directory writes: readers see the old content or the new, never a half.

Every result file of borescan is written through these helpers. A file is written to a
temporary name in the *same* directory (so the final :func:`os.replace` is a rename on one
filesystem), flushed and fsync'ed, then renamed over the target. A directory is built under a
temporary name next to the target and renamed into place when the ``with`` block succeeds; on
an exception the temporary directory is removed and the target is left as it was.

JSON is written with sorted keys, two-space indent, a trailing newline and Python's shortest
round-trip float repr, so the same data always gives the same bytes.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "json_ready",
    "atomic_write_bytes",
    "atomic_write_text",
    "atomic_write_json",
    "atomic_dir",
    "dumps_json",
]


def _fsync_dir(path: Path) -> None:
    """Flush a directory entry (the rename) to disk where the OS allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same dir + fsync + rename).

    Parent directories are created. Returns the path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)
    return path


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8, newlines written as given)."""
    return atomic_write_bytes(path, text.encode(encoding))


def json_ready(obj: Any) -> Any:
    """Make an object JSON-ready with a stable representation (the one JSON sanitiser of borescan).

    Non-finite floats become ``null`` (JSON has no NaN), tuples become lists, numpy scalars and
    arrays become Python numbers and lists, paths become strings.
    """
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if hasattr(obj, "tolist"):  # numpy arrays and scalars
        return json_ready(obj.tolist())
    if hasattr(obj, "isoformat"):  # date / datetime
        return obj.isoformat()
    raise TypeError(f"cannot write {type(obj).__name__} to JSON: {obj!r}")


def dumps_json(obj: Any) -> str:
    """Serialise ``obj`` to the canonical borescan JSON text (sorted keys, indent 2, newline).

    Floats use Python's shortest round-trip repr (``repr(0.1) == '0.1'``), so equal data always
    gives equal text; NaN and infinities are written as ``null``.
    """
    return json.dumps(json_ready(obj), sort_keys=True, indent=2, ensure_ascii=False, allow_nan=False) + "\n"


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as canonical JSON (see :func:`dumps_json`) to ``path`` atomically."""
    return atomic_write_text(path, dumps_json(obj))


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, replace: bool = True) -> Iterator[Path]:
    """Build a directory under a temporary name, then rename it to ``path``.

    Use as ``with atomic_dir(out) as tmp: (tmp / "a.json").write_text(...)``. On success the
    temporary directory becomes ``path``; an existing ``path`` is replaced when ``replace`` is
    true (it is moved aside first and removed after the rename) and ``FileExistsError`` is raised
    otherwise. On an exception the temporary directory is removed and ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        for root, _dirs, files in os.walk(tmp):
            for name in files:
                with open(os.path.join(root, name), "rb") as fh:
                    os.fsync(fh.fileno())
        os.chmod(tmp, 0o755)
        old = None
        if path.exists():
            if not replace:
                raise FileExistsError(f"{path} exists")
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            old.rmdir()
            os.replace(path, old)
        os.replace(tmp, path)
        _fsync_dir(path.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
