"""One writer per dataset: ``DatasetLock``, a lock file at the dataset's root naming its holder.

The lock file (``ROOT/.univtac-data.lock``) is not part of the format: readers never look at it, validators
ignore it, and copying a dataset without it loses nothing. It holds one JSON line, the holder's pid, host, start
time and command, so that a refused writer can say who holds the dataset.

* Local folders: the file is held with ``flock``, which the kernel releases when the holder exits, however it
  exits (SIGKILL too), and removed by a holder that releases it. A file that names a holder while nobody holds
  the ``flock`` is a stale lock, left by a killed writer; the next writer takes it over and names the dead
  holder in a warning.
* Object stores (fsspec URLs): a conditional create (the file is created only if absent). A file left by a
  writer whose process is gone on this same host is stale and taken over; one from another host is refused
  with its holder named, to be removed by hand when that writer is known to be gone.

Within one process the lock is re-entrant (a second ``DatasetWriter`` on the same folder in the same process
shares it): it keeps other processes out, not other objects.

    with DatasetLock("out/indenters"):   # raises DatasetLockedError (exit 2 in the CLI) when held elsewhere
        ...
"""

from __future__ import annotations

import atexit
import errno
import fcntl
import json
import logging
import os
import socket
import sys
import time
from dataclasses import dataclass

from univtac_data.storage.errors import DatasetError
from univtac_data.storage.fs import Location

LOCK_NAME = ".univtac-data.lock"
log = logging.getLogger("univtac_data")


class DatasetLockedError(DatasetError):
    """Another process holds the dataset's writer lock."""


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or held) a lock: from the lock file's JSON line."""

    pid: int
    host: str
    started: str = "?"
    command: str = "?"

    @classmethod
    def current(cls) -> LockHolder:
        argv = " ".join([os.path.basename(sys.argv[0]), *sys.argv[1:]]) if sys.argv and sys.argv[0] else "python"
        return cls(pid=os.getpid(), host=socket.gethostname(),
                   started=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), command=argv[:200])

    @classmethod
    def parse(cls, data: bytes) -> LockHolder | None:
        """The holder a lock file names, or None when it is empty or unreadable (a writer died mid-write)."""
        try:
            doc = json.loads(data.decode())
            return cls(pid=int(doc["pid"]), host=str(doc["host"]), started=str(doc.get("started", "?")),
                       command=str(doc.get("command", "?")))
        except (ValueError, KeyError, TypeError, UnicodeDecodeError):
            return None

    def to_bytes(self) -> bytes:
        return (json.dumps({"pid": self.pid, "host": self.host, "started": self.started,
                            "command": self.command}) + "\n").encode()

    def describe(self) -> str:
        return f"pid {self.pid} on {self.host} (since {self.started}: {self.command})"

    def is_gone(self) -> bool:
        """True when the holder is known dead: same host and no such process. Unknown (another host): False."""
        if self.host != socket.gethostname():
            return False
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:  # alive, another user's
            return False
        return False


@dataclass
class _Hold:
    """One process's hold on one lock file, shared by the ``DatasetLock`` objects of that folder."""

    fd: int | None  # the flock'd file (local folders)
    loc: Location
    count: int = 1


# in-process holds, by lock file URL
_HELD: dict[str, _Hold] = {}


class DatasetLock:
    """The writer lock of the dataset at ``path`` (a folder or fsspec URL). Use ``with`` or
    ``acquire``/``release``; ``stale`` is the dead holder taken over, if any. A lock object that is garbage
    collected releases its hold, so a forgotten ``DatasetWriter`` frees the dataset when it goes away.

    ``acquire`` raises ``DatasetLockedError`` (a ``DatasetError``: one line, the CLI exits 2) naming the holder.
    The dataset folder is created if missing (and removed again on release if the lock was all it held).
    """

    def __init__(self, path: str | os.PathLike[str] | Location) -> None:
        self.loc = path if isinstance(path, Location) else Location.parse(path)
        self.key = self.loc.url_of(LOCK_NAME)
        self.stale: LockHolder | None = None
        self._held = False

    def __enter__(self) -> DatasetLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        try:
            self.release()
        except Exception:  # interpreter teardown: the kernel frees the flock anyway
            pass

    @property
    def held(self) -> bool:
        return self._held

    def acquire(self) -> DatasetLock:
        if self._held:
            return self
        hold = _HELD.get(self.key)
        if hold is not None:
            hold.count += 1
            self._held = True
            return self
        created_root = False
        if not self.loc.exists():
            try:
                self.loc.makedirs("")
            except OSError as error:
                raise DatasetError(f"{self.loc.url}: cannot create the dataset folder "
                                   f"({error.strerror or error})") from None
            created_root = True
        elif self.loc.is_local and not os.path.isdir(self.loc.join("")):
            raise DatasetError(f"{self.loc.url}: is a file, not a dataset folder")
        fd = self._acquire_flock(created_root) if self.loc.is_local else self._acquire_create()
        _HELD[self.key] = _Hold(fd=fd, loc=self.loc)
        self._held = True
        if created_root:
            _CREATED.add(self.key)
        if self.stale is not None:
            log.warning("%s: took over a stale lock of %s (that writer is gone)", self.key, self.stale.describe())
        return self

    def release(self) -> None:
        if not self._held:
            return
        self._held = False
        hold = _HELD.get(self.key)
        if hold is None:
            return
        hold.count -= 1
        if hold.count > 0:
            return
        del _HELD[self.key]
        if hold.fd is not None:
            # remove the file while still holding it (a waiter that opened it sees it gone and retries); a lock
            # file that outlives its writer is therefore a stale one
            try:
                os.unlink(self.loc.join(LOCK_NAME))
            except FileNotFoundError:
                pass
            self._undo_root()
            os.close(hold.fd)  # releases the flock
            return
        if not self.loc.is_local:
            self.loc.remove(LOCK_NAME)
        self._undo_root()

    # local: flock ---------------------------------------------------------------------------------------------

    def _acquire_flock(self, created_root: bool) -> int:
        path = self.loc.join(LOCK_NAME)
        for _attempt in range(10):
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as error:
                if created_root:
                    _remove_if_empty(self.loc)
                raise DatasetError(f"{path}: cannot create the writer lock ({error.strerror or error})") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                busy = error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)
                holder = _wait_for_holder(fd) if busy else None
                os.close(fd)
                if busy:
                    raise DatasetLockedError(_locked_message(self.loc.url, holder, None)) from None
                raise DatasetError(f"{path}: cannot lock ({error.strerror or error})") from None
            # a holder removes the file when it releases: the file locked must still be the one at the path
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(path))
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            self.stale = LockHolder.parse(_read_fd(fd))
            os.ftruncate(fd, 0)
            os.pwrite(fd, LockHolder.current().to_bytes(), 0)
            os.fsync(fd)
            return fd
        raise DatasetLockedError(_locked_message(self.loc.url, None, None))

    # object stores: conditional create -------------------------------------------------------------------------

    def _acquire_create(self) -> None:  # no file descriptor: the lock is the object itself
        path = self.loc.join(LOCK_NAME)
        mine = LockHolder.current().to_bytes()
        for _attempt in range(2):
            try:
                with self.loc.fs.open(path, "xb") as handle:  # create only if absent (If-None-Match on S3)
                    handle.write(mine)
                atexit.register(_release_at_exit, self.key)
                return None
            except FileExistsError:
                pass
            except (ValueError, NotImplementedError):
                # a file system without exclusive create: check, then write (a narrow race remains)
                if not self.loc.exists(LOCK_NAME):
                    self.loc.fs.pipe_file(path, mine)
                    atexit.register(_release_at_exit, self.key)
                    return None
            try:
                holder = LockHolder.parse(self.loc.read_bytes(LOCK_NAME))
            except FileNotFoundError:
                continue  # released in between: try again
            if holder is not None and holder.is_gone():
                self.stale = holder
                self.loc.remove(LOCK_NAME)
                continue
            raise DatasetLockedError(_locked_message(self.loc.url, holder, self.key))
        raise DatasetLockedError(_locked_message(self.loc.url, None, self.key))

    def _undo_root(self) -> None:
        """Remove the dataset folder again when this lock created it and it holds nothing else."""
        if self.key in _CREATED:
            _CREATED.discard(self.key)
            _remove_if_empty(self.loc)


_CREATED: set[str] = set()  # lock keys whose acquire created the dataset folder


def _remove_if_empty(loc: Location) -> None:
    if not loc.is_local or not set(os.listdir(loc.root)) <= {LOCK_NAME}:
        return
    try:
        if os.path.exists(loc.join(LOCK_NAME)):
            os.remove(loc.join(LOCK_NAME))
        os.rmdir(loc.root)
    except OSError:  # another writer arrived in between: its folder now
        pass


def _release_at_exit(key: str) -> None:
    """Object stores keep a lock file after the process ends: remove ours at exit."""
    hold = _HELD.pop(key, None)
    if hold is not None and hold.fd is None:
        hold.loc.remove(LOCK_NAME)


def _read_fd(fd: int) -> bytes:
    return os.pread(fd, 4096, 0)


HOLDER_WAIT_S = 2.0  # a writer names itself right after taking the flock; on a loaded machine that can lag


def _wait_for_holder(fd: int, wait_s: float = HOLDER_WAIT_S) -> LockHolder | None:
    """The holder named in a flock'd lock file, re-read for up to ``wait_s`` seconds: a writer refused in the
    instant between another's flock and its pid being written would otherwise name nobody."""
    deadline = time.monotonic() + wait_s
    while True:
        holder = LockHolder.parse(_read_fd(fd))
        if holder is not None or time.monotonic() >= deadline:
            return holder
        time.sleep(0.02)


def _locked_message(url: str, holder: LockHolder | None, lock_path: str | None) -> str:
    """One line naming the holder; ``lock_path`` when the lock does not free itself (object stores)."""
    who = holder.describe() if holder is not None else "another process (its lock file names no holder yet)"
    if lock_path is None:  # flock: freed by the kernel when the holder exits
        return f"{url}: another writer is using this dataset: {who}; wait for it to finish"
    return f"{url}: another writer is using this dataset: {who}; wait for it to finish, or remove {lock_path} " \
           "if that writer is gone"
