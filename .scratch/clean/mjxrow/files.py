"""Output files of every command: the output folder checked before any work, atomic writes, and a
lock so that two runs never write one folder.

- `check_out_dir(path)` proves, before a command works, that it can create and write the folder
  (`--out /proc/x` fails at once, not after minutes of work); it leaves nothing behind.
  `check_new_file(path)` refuses a file an earlier run left there, unless the command was asked
  to replace it (`--overwrite`).
- `atomic_write_*` write a temp file in the same folder, then `os.replace` it: a reader (or a
  resumed run) sees the old file or the new one, never half of one; a failed write removes its
  temp file.
- `OutLock(folder)` holds `folder/.lock` (an OS file lock, released when the process ends, even
  by a kill) and refuses a second holder with a one-line error.
"""

from __future__ import annotations

import errno
import os
import re
import tempfile
from pathlib import Path

import filelock


class OutputError(ValueError):
    """A one-line error about an output folder or file; the message starts with the option."""


def check_out_dir(path: str | Path, option: str = "--out") -> Path:
    """The folder `path` as an absolute Path once it is known that it can be created and written.

    Creates nothing that outlives the check: a probe file (or folder) in the folder (or in its
    nearest existing parent) is made and removed. OutputError naming `option` and the reason."""
    p = Path(path).expanduser().absolute()
    try:  # a name too long (ENAMETOOLONG) or a folder we may not look into (EACCES)
        probe_in = p
        while not probe_in.exists():
            if probe_in.parent == probe_in:
                break
            probe_in = probe_in.parent
        if p.exists() and not p.is_dir():
            raise OutputError(f"{option} {path}: exists and is not a folder")
        if not probe_in.is_dir():
            raise OutputError(f"{option} {path}: cannot write there ({probe_in} is not a "
                              "folder)")
    except OSError as e:
        raise OutputError(f"{option} {_short(path)}: not a usable path "
                          f"({e.strerror or e})") from None
    try:
        if probe_in == p:
            fd, name = tempfile.mkstemp(prefix=".probe-", dir=p)
            os.close(fd)
            os.unlink(name)
        else:
            os.rmdir(tempfile.mkdtemp(prefix=".probe-", dir=probe_in))
    except OSError as e:
        raise OutputError(f"{option} {path}: cannot write in {probe_in} "
                          f"({e.strerror or e})") from None
    return p


def _short(path: str | Path, n: int = 80) -> str:
    """`path` for a message: at most `n` characters (a 300-character name, elided)."""
    s = str(path)
    return s if len(s) <= n else f"{s[:n // 2]}…{s[-n // 2:]}"


def check_out_file(path: str | Path, option: str = "--out") -> Path:
    """`check_out_dir` for the folder of a file to write; the file itself must not be a folder."""
    p = Path(path).expanduser().absolute()
    try:
        is_dir = p.is_dir()
    except OSError as e:
        raise OutputError(f"{option} {_short(path)}: not a usable path "
                          f"({e.strerror or e})") from None
    if is_dir:
        raise OutputError(f"{option} {path}: is a folder, expected a file name")
    check_out_dir(p.parent, option)
    return p


def check_new_file(path: str | Path, option: str = "--out", flag: str = "--overwrite",
                   exists: bool | None = None) -> Path:
    """`path` as given when no file is there yet: a command never replaces a file it did not
    write unless asked. OutputError naming `option`, the file and `flag` (the option that
    allows the replacement) when one is there; `exists` overrides the look (several processes:
    the writing process's answer)."""
    p = Path(path)
    if p.exists() if exists is None else exists:
        raise OutputError(f"{option} {p.parent}: {p} already exists (an earlier run's); choose "
                          f"another {option} or pass {flag} to replace it")
    return p


def _tmp(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)  # the disk (or quota) is full


def _full(path: Path, e: OSError) -> OutputError:
    """OutputError (one line, naming the file) for a write that found the disk full."""
    return OutputError(f"{path}: cannot be written ({e.strerror or e}); nothing half-written is "
                       "left: free some space and run the same command again")


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write `data` to `path` atomically (temp file in the same folder, then os.replace). A
    full disk is an OutputError naming the file, and leaves the old file (if any) and no
    temp file."""
    path = Path(path)
    tmp = _tmp(path)
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as e:
        if e.errno in FULL:
            raise _full(path, e) from None
        raise
    finally:
        tmp.unlink(missing_ok=True)
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically."""
    return atomic_write_bytes(path, text.encode())


def atomic_save(path: str | Path, save) -> Path:
    """Call `save(tmp_path)` (e.g. `fig.savefig`, `image.save`), then move the result onto
    `path` atomically; the temp file keeps `path`'s suffix so that writers can read the format
    from it."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        save(tmp)
        os.replace(tmp, path)
    except OSError as e:
        if e.errno in FULL:
            raise _full(path, e) from None
        raise
    finally:
        tmp.unlink(missing_ok=True)
    return path


# what `_tmp` and `atomic_save` name their temp files: .NAME.PID.tmp or .STEM.PID.tmp.SUFFIX
TEMP_NAME = re.compile(r"^\..+\.[0-9]+\.tmp(\.[A-Za-z0-9]+)?$")


def temp_files(folder: str | Path) -> list[Path]:
    """Temp files that an interrupted atomic write of ours may have left in `folder` (not
    recursive; only names as `_tmp` and `atomic_save` make them: another file is not ours)."""
    folder = Path(folder)
    return sorted(p for p in folder.iterdir() if TEMP_NAME.match(p.name) and p.is_file()) \
        if folder.is_dir() else []


class OutLock:
    """`with OutLock(folder):` holds `folder/.lock`; a second holder, in this or another
    process, gets OutputError at once. The OS releases the lock when the process ends."""

    def __init__(self, folder: str | Path, option: str = "--out"):
        self.folder, self.option = Path(folder), option
        self._lock = filelock.FileLock(str(self.folder / ".lock"), timeout=0,
                                       is_singleton=False)

    def __enter__(self) -> OutLock:
        try:
            self._lock.acquire()
        except filelock.Timeout:
            raise OutputError(f"{self.option} {self.folder}: another run is writing this folder "
                              f"(it holds {self.folder / '.lock'}); wait for it to end or choose "
                              "another --out") from None
        return self

    def __exit__(self, *exc) -> None:
        self._lock.release()
