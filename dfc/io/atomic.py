"""Atomic output: write to a temporary file beside the target, then ``os.replace`` it into place,
so an interrupted or failed write never leaves a partial file under the target name."""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path in the target's directory; on success rename it to ``path``.

    The temporary name keeps the target's suffix so suffix-sniffing writers (OpenEXR, Pillow)
    behave. On any exception the temporary file is removed and the target is left untouched.
    An ``OSError`` — the directory missing or unwritable, the disk full, the rename refused — names the target,
    never the temporary file (a user asked for the target).
    """
    target = Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    if not directory.is_dir():
        raise FileNotFoundError(2, "output directory does not exist", str(directory))
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{target.suffix}", dir=directory)
        os.close(fd)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a finished file gets the usual permissions
        yield Path(tmp)
        os.replace(tmp, target)
    except BaseException as e:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        if isinstance(e, OSError) and (_is_temporary(e.filename, directory, target)
                                       or (e.filename is None and e.errno in _WRITE_ERRNOS)):
            e.filename, e.filename2 = str(target), None
        raise


_WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO)
"""Errors of a write that carry no file name (the output they are about is the target)."""


def _is_temporary(name, directory: Path, target: Path) -> bool:
    """Whether an error's file name is one of ``atomic_path``'s temporary files for ``target``."""
    if name is None:
        return False
    name = Path(os.fsdecode(name))
    return name.parent == directory and name.name.startswith(f".{target.name}.") and ".tmp" in name.name


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file + fsync + rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
