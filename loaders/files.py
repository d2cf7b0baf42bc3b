"""``EpisodeFiles``: the HDF5 episode files one reader reads without h5py, through cached layouts.

For each recently read file: the ``EpisodeLayout`` the process's ``LayoutCache`` keeps for it, checked
against the file on disk, and a read-only descriptor of the reader's own (``os.open`` costs about 6 us
where an h5py open costs 0.2 ms, and 2 to 5 ms with the layout built again). Descriptors are per reader,
so per thread: one thread never closes a descriptor another is reading through, and a closed number
reused for another file can never be read by a source taken before (none is closed while a batch holds
them). Bounded: at most ``max_open`` files, least recently used closed first.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from univtac_data.loaders.chunks import FrameSource
from univtac_data.loaders.layouts import EpisodeLayout, FileIdentity, LayoutCache

DEFAULT_MAX_OPEN_FILES = 32   # per reader, so per thread: 2 threads keep at most 2 x (32 + 16 handles) open


@dataclass
class CachedFile:
    """One episode file as a reader knows it: the version it checked, that version's layout, its descriptor."""

    path: str
    identity: FileIdentity            # the version on disk when last checked
    layout: EpisodeLayout             # of that version (refreshed from the cache at every check: it grows)
    checked: int                      # the reader's generation (batch) of that check
    descriptor: int = -1              # read-only descriptor of that version, opened on the first frame read
    sources: dict[str, FrameSource] = field(default_factory=dict)   # frame sources through ``descriptor``


class EpisodeFiles:
    """A reader's ``CachedFile`` per path, in least-recently-used order (see the module docstring)."""

    def __init__(self, layouts: LayoutCache, max_open: int = DEFAULT_MAX_OPEN_FILES) -> None:
        if max_open < 1:
            raise ValueError(f"max_open_files must be >= 1 (got {max_open})")
        self.layouts, self.max_open = layouts, max_open
        self._files: OrderedDict[str, CachedFile] = OrderedDict()
        self._retired: list[int] = []   # descriptors to close once no batch holds them

    def __del__(self) -> None:
        # plain descriptors, unlike h5py handles, are not closed when their owner is collected
        if "_files" in self.__dict__:   # not when __init__ raised
            self.close()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_files"], state["_retired"] = OrderedDict(), []
        return state

    def lookup(self, path: str, generation: int) -> tuple[CachedFile | None, bool]:
        """``(file, replaced)``: ``path`` with a layout of the version now on disk (``None`` when the cache has
        none for that version: read it through h5py, which records one), and whether the version this reader
        last read differs from that (its h5py handle, if any, reads an older file). The check (a ``stat``,
        about 3 us) runs once per ``generation``."""
        file = self._files.get(path)
        if file is not None:
            self._files.move_to_end(path)
            if file.checked == generation:
                return file, False
        layout = self.layouts.get(path)
        if layout is None and file is None:
            return None, False   # nothing kept to check: h5py reads it (and records a layout)
        try:
            identity = FileIdentity.of(os.stat(path))
        except OSError:   # missing or unreadable: h5py raises the one-line error
            self._drop(path)
            return None, file is not None
        replaced = file is not None and file.identity != identity
        if layout is not None and layout.identity != identity:
            self.layouts.discard(path, layout.identity)   # a former version's places must never be read
            layout = None
        if layout is None:
            self._drop(path)
            return None, replaced
        if file is None or replaced:
            self._drop(path)
            file = self._files[path] = CachedFile(path, identity, layout, generation)
        file.layout, file.checked = layout, generation
        return file, replaced

    def descriptor(self, file: CachedFile) -> int:
        """``file``'s descriptor, opened now if need be; -1 when the path holds another version by now."""
        if file.descriptor < 0:
            try:
                descriptor = os.open(file.path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
            except OSError:
                return -1
            try:
                same = FileIdentity.of(os.fstat(descriptor)) == file.identity
            except OSError:
                same = False
            if not same:   # replaced between the check and the open: h5py reads it this time
                os.close(descriptor)
                return -1
            file.descriptor = descriptor
        return file.descriptor

    def _drop(self, path: str) -> None:
        file = self._files.pop(path, None)
        if file is not None and file.descriptor >= 0:
            self._retired.append(file.descriptor)

    def trim(self) -> None:
        """Close descriptors down to ``max_open`` files (least recently used first) and any retired ones.
        Call only when no batch holds sources."""
        while len(self._files) > self.max_open:
            self._drop(next(iter(self._files)))
        retired, self._retired = self._retired, []
        for descriptor in retired:
            _close(descriptor)

    @property
    def n_open(self) -> int:
        """Descriptors open now."""
        return sum(f.descriptor >= 0 for f in self._files.values()) + len(self._retired)

    def close(self) -> None:
        """Close every descriptor (a forked child closes its copies: the parent's stay open)."""
        for path in list(self._files):
            self._drop(path)
        self.trim()


def _close(descriptor: int) -> None:
    try:
        os.close(descriptor)
    except OSError:
        pass
