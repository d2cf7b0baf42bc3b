"""``FrameBatchLoader``: batches of a ``TactileFrameDataset`` decoded by threads of the training process.

Why threads and not DataLoader worker processes: a compact 320 x 240 sample is 0.6 MB, and a worker
process must write it to fresh shared memory that the kernel maps page by page (about 0.4 ms a sample
on a 2-core VM, as much as half the decode itself; ``benchmarks/loader_throughput.py``). Blosc decodes
without the GIL, so threads decode in parallel into batch tensors the training process owns, and
nothing crosses a process boundary. Each thread reads through its own ``EpisodeReader`` (its own
handles and descriptors), so none is shared or closed under another thread; the readers share the
dataset's layout cache, so an episode of a large dataset is opened with h5py about once per pad it is
read for (in the first epoch), not once per sample (``layouts.py``).

Batch memory is reused once the training loop has dropped every tensor of a batch (``BatchBuffers``).
Batches have the dataset's layout: with ``TactileFrameDataset(..., compact=True, channels_last=True)`` (the
fast path) each image chunk decodes straight into its batch slot and nothing is copied after the decode.

Where one thread's CPU time goes per compact 320 x 240 sample, channels-last (``benchmarks/
loader_throughput.py`` has the stages): Blosc-zstd decode 0.6 ms (the floor; without the GIL), reading
the three chunks 0.02 ms (``os.pread``, without the GIL), their Fletcher-32 0.03 ms, Python and the small
targets under 0.1 ms: about 0.7 CPU-ms, and 0.8 to 0.9 with two threads (GIL hand-overs included).

Use DataLoader workers instead when samples need Python work per sample (a ``transform``); with a
transform this loader still works, but the per-sample work holds the GIL.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from univtac_data.loaders.buffers import BatchBuffers
from univtac_data.loaders.episodes import EpisodeReader
from univtac_data.loaders.frames import Sample, TactileFrameDataset


class FrameBatchLoader:
    """Iterates over batches of ``dataset``: each batch exactly ``default_collate`` of its samples, as a
    ``DataLoader(dataset, batch_size, shuffle)`` would give, read by ``threads`` threads of this process.

    Arguments: ``batch_size``; ``shuffle`` (epoch e uses seed ``seed + e``; the epoch advances after every
    full pass, or set it with ``set_epoch``); ``drop_last``; ``batch_sampler``: any iterable of index lists
    instead (e.g. ``SensorBatchSampler`` for datasets that mix sensors); ``threads``: decoding threads
    (about one per core); ``prefetch``: batches decoded ahead per thread.
    """

    def __init__(self, dataset: TactileFrameDataset, batch_size: int = 32, *, shuffle: bool = True,
                 drop_last: bool = False, seed: int = 0, threads: int = 2, prefetch: int = 2,
                 batch_sampler: Iterable[Sequence[int]] | None = None) -> None:
        if batch_size < 1 or threads < 1 or prefetch < 0:
            raise ValueError(f"need batch_size >= 1, threads >= 1, prefetch >= 0 "
                             f"(got {batch_size}, {threads}, {prefetch})")
        self.dataset, self.batch_size, self.shuffle, self.drop_last = dataset, batch_size, shuffle, drop_last
        self.seed, self.threads, self.prefetch, self.batch_sampler = seed, threads, prefetch, batch_sampler
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _index_batches(self) -> list[list[int]]:
        if self.batch_sampler is not None:
            return [list(map(int, batch)) for batch in self.batch_sampler]
        n = len(self.dataset)
        order = np.random.default_rng(self.seed + self.epoch).permutation(n) if self.shuffle else np.arange(n)
        stop = n - n % self.batch_size if self.drop_last else n
        return [order[k:k + self.batch_size].tolist() for k in range(0, stop, self.batch_size)]

    def __len__(self) -> int:
        return len(self._index_batches())

    def __iter__(self) -> Iterator[Sample]:
        batches = iter(self._index_batches())
        local, readers = threading.local(), list[EpisodeReader]()

        def load(indices: list[int]) -> Sample:
            if not hasattr(local, "reader"):   # per thread: handles used and closed by that thread only
                local.reader = self.dataset.reader.sibling()   # shares the dataset's layout cache
                local.buffers = BatchBuffers()
                readers.append(local.reader)
            return self.dataset.read_batch(indices, reader=local.reader, buffers=local.buffers)

        pool = ThreadPoolExecutor(self.threads, thread_name_prefix="univtac-frames")
        pending: deque[Future[Sample]] = deque()
        try:
            for indices in batches:
                pending.append(pool.submit(load, indices))
                if len(pending) >= self.threads * (1 + self.prefetch):
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
            self.epoch += 1
        finally:
            for future in pending:
                future.cancel()
            pool.shutdown(wait=True)
            for reader in readers:
                reader.close()
