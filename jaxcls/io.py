"""The one way files and folders are written: atomically, so that an interrupted run never leaves a
half-written result (a reader sees the old content or the new one, never a mix).

- ``atomic_write(path)``: a file written to a hidden temporary sibling, flushed to disk and renamed into
  place (``os.replace`` is atomic on POSIX); ``write_text``/``write_bytes``/``write_json`` wrap it.
- ``atomic_folder(folder)``: a folder built in a hidden temporary sibling and swapped into place.
- ``append_jsonl(path, records)`` / ``read_jsonl(path)``: a log that grows a record per line, each append
  flushed to disk; a line torn by an interruption is dropped on read and cut off before the next append.
  ``JsonlFollower``: logs other processes are appending to, read as they grow.
- ``check_out_dir(folder)``: an output folder checked before any work (not a file, writable), so that a run
  never computes for minutes and then fails to save.
"""

from __future__ import annotations

import contextlib
import gzip
import json
import lzma
import os
import shutil
import tempfile
import threading
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any


def check_out_dir(folder: str | os.PathLike, key: str = "out_dir", whole: bool = False) -> Path:
    """Refuse an output folder that cannot be written, before any work is done: ``folder`` (or a folder on
    its path) is a file, or the folder the run will write in cannot be written. Creates nothing; returns
    ``folder`` resolved. Raises ValueError (a file) or OSError (no write access) naming ``key``.

    whole: the folder is written whole beside itself and renamed into place (``atomic_folder``), or may go to
    a numbered sibling, so its parent must be writable; else files are written into the folder itself (its
    nearest existing ancestor when it does not exist yet). Writability is probed by creating and removing a
    hidden file, so that it holds for read-only mounts and whatever the permission bits say to root.
    """
    path = Path(folder).expanduser().resolve()
    if not path.name:
        raise ValueError(f"{key}: must name a folder below the root, got {str(folder)!r}")
    existing = next(p for p in (path, *path.parents) if p.exists() or p.is_symlink())
    if not existing.is_dir():
        if existing == path:
            raise ValueError(f"{key}: {folder} is a file, not a folder; choose another {key} (--overwrite "
                             "replaces a folder's content, never a file)")
        raise ValueError(f"{key}: {folder} lies under {existing}, which is a file, not a folder; choose another "
                         f"{key}")
    probe_in = existing
    if whole and existing == path:
        probe_in = path.parent
    try:
        with tempfile.NamedTemporaryFile(dir=probe_in, prefix=".jaxcls-write-check-"):
            pass
    except OSError as e:
        raise OSError(f"{key}: cannot write in {probe_in} ({e.strerror or e}); choose a writable {key}") from None
    return path


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, binary: bool = True) -> Iterator[IO]:
    """Open a temporary sibling of ``path`` for writing; on success it is fsync'ed and renamed to ``path``.

    On an exception the temporary file is removed and ``path`` is untouched. Parent folders are created.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, cannot write a file there")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        with open(tmp, "wb" if binary else "w") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_write(path) as f:
        f.write(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_bytes(path, text.encode())


def write_json(path: str | os.PathLike, data: Any, indent: int | None = 1) -> Path:
    """Write ``data`` as strict JSON (no NaN) to ``path`` atomically."""
    return write_text(path, json.dumps(data, indent=indent, allow_nan=False) + "\n")


def read_weights(path: str | os.PathLike, template: Any, owner: str, meaning: str) -> Any:
    """The arrays of the msgpack file ``path`` (flax's serialised state dict, as ``write_bytes`` wrote it) in the
    structure of ``template`` (a pytree of shapes, e.g. ``jax.eval_shape`` of the network's init), every leaf's shape
    checked. ValueError ``"<owner>: <path> does not hold <meaning>: ..."`` where the structure differs, and ``"<owner>:
    <path>: <layer> has shape ..., expected ... for <meaning>"`` naming the first leaf of another shape."""
    import jax
    import numpy as np
    from flax import serialization

    path = Path(path)
    try:
        weights = serialization.from_state_dict(template, serialization.msgpack_restore(path.read_bytes()))
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{owner}: {path} does not hold {meaning}: {e}") from None
    for (keypath, want), got in zip(jax.tree_util.tree_leaves_with_path(template), jax.tree.leaves(weights),
                                    strict=True):
        if np.shape(got) != want.shape:
            raise ValueError(f"{owner}: {path}: {jax.tree_util.keystr(keypath)} has shape {np.shape(got)}, expected "
                             f"{want.shape} for {meaning}")
    return weights


def read_json_object(path: str | os.PathLike, error: type[Exception] = ValueError) -> dict[str, Any]:
    """The JSON object in ``path``; ``error`` naming the file when it is missing, not JSON or not an object."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: missing")
    try:
        data = json.loads(path.read_text())
    except ValueError as e:
        raise error(f"{path}: invalid JSON ({e})") from e
    if not isinstance(data, dict):
        raise error(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


@contextlib.contextmanager
def atomic_folder(folder: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary sibling of ``folder`` to fill; on success it replaces ``folder``.

    An existing ``folder`` (or a link) is moved aside first and removed after the swap (best effort: a
    leftover ``.<name>.old-*`` is harmless); callers decide whether replacing it is allowed. On an exception
    the temporary folder is removed and ``folder`` is as it was (moved back if the swap itself failed).
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = folder.parent / f".{folder.name}.tmp-{uuid.uuid4().hex[:12]}"
    tmp.mkdir()  # plain mkdir: the final folder gets the usual umask permissions (mkdtemp gives 0700)
    try:
        yield tmp
        if folder.exists() or folder.is_symlink():
            old = folder.parent / f".{folder.name}.old-{uuid.uuid4().hex[:12]}"
            folder.rename(old)
            try:
                tmp.rename(folder)
            except OSError:
                old.rename(folder)
                raise
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:
                old.unlink(missing_ok=True)
        else:
            tmp.rename(folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# Compressed JSONL archives (``xz -k episodes.jsonl``: a finished run's records kept in results/), by suffix.
_ARCHIVE_OPENERS = {".xz": lzma.open, ".gz": gzip.open}


def read_jsonl(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The records of a JSONL log (``append_jsonl``) or of its archive (``.xz``, ``.gz``: read as compressed);
    [] if it does not exist. A last line without its newline (torn by an interruption) is left out; a damaged
    line elsewhere is a ValueError naming it."""
    path = Path(path)
    if not path.exists():
        return []
    opener = _ARCHIVE_OPENERS.get(path.suffix)
    if opener is None:
        text = path.read_text()
    else:
        with opener(path, "rt") as f:
            text = f.read()
    lines = text.split("\n")
    complete = lines[:-1]  # the piece after the last newline is empty, or torn
    records = []
    for number, line in enumerate(complete, 1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: line {number} is not a JSON record ({e})") from None
    return records


def _byte_at(f: IO[bytes], at: int) -> bytes:
    f.seek(at)
    return f.read(1)


def _after_last_newline(f: IO[bytes], end: int, block: int = 1 << 16) -> int:
    """The offset just after the last newline before ``end`` in ``f`` (0 if none), read backwards in blocks."""
    while end > 0:
        start = max(0, end - block)
        f.seek(start)
        found = f.read(end - start).rfind(b"\n")
        if found >= 0:
            return start + found + 1
        end = start
    return 0


class JsonlFollower:
    """Reads JSONL logs that other processes are appending to (``append_jsonl``) while they grow: a thread
    reads each file's new complete lines every ``interval`` s (the files: ``paths()``, asked again each time);
    ``finish()`` stops it, reads what is left (a last line without its newline is torn and left out, as
    ``read_jsonl`` does) and returns every record read, file by file. Parsing a large log takes seconds
    (~65 us a Table 1 record); done while the writers work, it is done when they end."""

    def __init__(self, paths: Callable[[], list[Path]], interval: float = 1.0) -> None:
        self._paths, self._interval = paths, interval
        self._read: dict[Path, tuple[int, list[dict[str, Any]]]] = {}  # path -> (offset read to, its records)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._follow, name="jsonl-follower", daemon=True)
        self._thread.start()

    def _follow(self) -> None:
        while not self._stop.wait(self._interval):
            try:
                self._poll()
            except ValueError:  # (a damaged line: ``finish`` reads it again and raises)
                return

    def _poll(self) -> None:
        for path in self._paths():
            offset, records = self._read.get(path, (0, []))
            try:
                with open(path, "rb") as f:
                    f.seek(offset)
                    data = f.read()
            except FileNotFoundError:
                continue
            complete = data[:data.rfind(b"\n") + 1]
            for number, line in enumerate(complete.decode().split("\n")[:-1], 1):
                if line.strip():
                    try:
                        records.append(json.loads(line))
                    except json.JSONDecodeError as e:
                        raise ValueError(f"{path}: a line after byte {offset} (its {number}.) is not a JSON record "
                                         f"({e})") from None
            self._read[path] = (offset + len(complete), records)

    def count(self) -> int:
        """How many records have been read so far (a progress count while the writers work)."""
        return sum(len(records) for _, records in list(self._read.values()))

    def records(self) -> list[dict[str, Any]]:
        """Every record read so far, file by file (the order ``finish`` returns them in), the writers still at work."""
        read = dict(self._read)
        return [r for path in self._paths() for r in read.get(path, (0, []))[1]]

    def finish(self) -> list[dict[str, Any]]:
        self._stop.set()
        self._thread.join()
        self._poll()
        return [r for path in self._paths() for r in self._read.get(path, (0, []))[1]]


def append_jsonl(path: str | os.PathLike, records: list[dict[str, Any]]) -> Path:
    """Append ``records`` to a JSONL log, one strict-JSON line each, flushed and fsync'ed; a torn last line
    (no newline: an interrupted append) is cut off first, so that a rerun continues on a clean record."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = "".join(json.dumps(r, allow_nan=False) + "\n" for r in records).encode()
    if path.exists():
        with open(path, "r+b") as f:
            end = f.seek(0, os.SEEK_END)
            if end and _byte_at(f, end - 1) != b"\n":
                f.truncate(_after_last_newline(f, end))
    with open(path, "ab") as f:
        f.write(payload)
        f.flush()
        os.fsync(f.fileno())
    return path
