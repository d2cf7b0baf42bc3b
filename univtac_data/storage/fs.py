"""File-system helpers: local paths and fsspec URLs behind one small interface.

Local paths get POSIX guarantees (write to a temporary name, fsync, ``os.replace``). Object stores have no
rename; there an object appears whole when its upload completes, which gives the same visibility rule.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from typing import Any

import fsspec
from fsspec.implementations.local import LocalFileSystem

TMP_PREFIX = ".tmp-"
# the optional extra (pyproject.toml) that installs each object store's fsspec implementation
PROTOCOL_EXTRAS = {"s3": "s3", "s3a": "s3", "gs": "gcs", "gcs": "gcs"}
_HASH_BLOCK = 1 << 20


@dataclass(frozen=True)
class Location:
    """A dataset root: the fsspec file system and the root path inside it."""

    fs: Any
    root: str
    url: str

    @classmethod
    def parse(cls, url_or_path: str | os.PathLike[str]) -> Location:
        """The location of ``url_or_path``. A URL whose protocol is unknown, or needs a package that is not
        installed (s3fs, gcsfs), is a ``DatasetError`` naming the URL and what to install."""
        from univtac_data.storage.errors import DatasetError

        text = os.fspath(url_or_path)
        protocol = text.split("://", 1)[0] if "://" in text else "file"
        try:
            fs, root = fsspec.core.url_to_fs(text)
        except ImportError:
            extra = PROTOCOL_EXTRAS.get(protocol)
            how = f"pip install 'univtac-data[{extra}]'" if extra else "install the fsspec implementation for it"
            raise DatasetError(f"{text}: reading {protocol}:// URLs needs a package that is not installed; "
                               f"{how}") from None
        except ValueError as error:
            if "Protocol not known" not in str(error):
                raise
            raise DatasetError(f"{text}: unsupported URL scheme {protocol}://; use a local path or an fsspec URL "
                               f"(file://, memory://, s3://, gs://, ...)") from None
        if isinstance(fs, LocalFileSystem):
            root = os.path.abspath(root)
        return cls(fs=fs, root=root.rstrip("/") or "/", url=text)

    @property
    def protocol(self) -> str:
        return self.fs.protocol if isinstance(self.fs.protocol, str) else self.fs.protocol[0]

    @property
    def is_local(self) -> bool:
        return isinstance(self.fs, LocalFileSystem)

    def join(self, *parts: str) -> str:
        return "/".join([self.root, *parts])

    def url_of(self, relpath: str) -> str:
        """A URL (or local path) for ``relpath`` that zarr and fsspec accept."""
        if self.is_local:
            return os.path.join(self.root, relpath)
        protocol = self.fs.protocol if isinstance(self.fs.protocol, str) else self.fs.protocol[0]
        return f"{protocol}://{self.join(relpath)}"

    def exists(self, relpath: str = "") -> bool:
        return bool(self.fs.exists(self.join(relpath) if relpath else self.root))

    def read_bytes(self, relpath: str) -> bytes:
        return bytes(self.fs.cat_file(self.join(relpath)))

    def write_bytes_atomic(self, relpath: str, data: bytes) -> None:
        """Replace ``relpath`` with ``data`` so that readers see the old or the new file, never a mix."""
        target = self.join(relpath)
        if not self.is_local:
            self.fs.pipe_file(target, data)
            return
        os.makedirs(os.path.dirname(target), exist_ok=True)
        tmp = os.path.join(os.path.dirname(target), f"{TMP_PREFIX}{os.getpid()}-{os.path.basename(target)}")
        with open(tmp, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
        fsync_dir(os.path.dirname(target))

    def makedirs(self, relpath: str) -> None:
        self.fs.makedirs(self.join(relpath), exist_ok=True)

    def listdir(self, relpath: str) -> list[str]:
        """Names (not paths) directly under ``relpath``; empty when it does not exist."""
        path = self.join(relpath)
        if not self.fs.exists(path):
            return []
        return sorted(p.rstrip("/").rsplit("/", 1)[-1] for p in self.fs.ls(path, detail=False))

    def files_under(self, relpath: str) -> list[str]:
        """Every file under ``relpath`` (itself if it is a file), relative to the root, sorted."""
        path = self.join(relpath)
        if self.fs.isfile(path):
            return [relpath]
        prefix = self.root.rstrip("/") + "/"
        return sorted(p[len(prefix):] for p in self.fs.find(path))

    def size(self, relpath: str) -> int:
        return int(self.fs.size(self.join(relpath)))

    def sha256(self, relpath: str) -> str:
        digest = hashlib.sha256()
        with self.fs.open(self.join(relpath), "rb") as handle:
            while block := handle.read(_HASH_BLOCK):
                digest.update(block)
        return digest.hexdigest()

    def remove(self, relpath: str) -> None:
        path = self.join(relpath)
        if self.fs.exists(path):
            self.fs.rm(path, recursive=True)


def fsync_dir(path: str) -> None:
    """Make a rename in ``path`` durable (POSIX)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(path: str) -> None:
    """fsync every file under a local directory (or the file itself)."""
    if os.path.isfile(path):
        with open(path, "rb") as handle:
            os.fsync(handle.fileno())
        return
    for folder, _dirs, files in os.walk(path):
        for name in files:
            with open(os.path.join(folder, name), "rb") as handle:
                os.fsync(handle.fileno())
        fsync_dir(folder)
