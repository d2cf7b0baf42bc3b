"""``TactileFrameDataset``: one sample per (frame, pad), with the UniVTAC encoder's pretraining targets.

Targets (paper symbols; shapes for one sample, ``H x W`` the sensor's native image size)::

    key            symbol    shape      dtype    values
    marked_rgb     I_marked  (3, H, W)  float32  tactile image with markers, RGB / 255, in [0, 1]
    pure_rgb       I_pure    (3, H, W)  float32  marker-free image, RGB / 255, in [0, 1]
    depth_mm       D         (1, H, W)  float32  indentation depth, mm (stored um / 1000), >= 0
    markers        M         (N, 2)     float32  current marker centres (u, v) scaled to [-1, 1]:
                                                 2 u / (W - 1) - 1, 2 v / (H - 1) - 1 (pixel centres at
                                                 integers; torch grid_sample's align_corners=True)
    object_pose    p         (7,)       float32  object pose in the gel-pad-centre frame: x, y, z in mm,
                                                 quaternion w, x, y, z with w >= 0 (q and -q are one
                                                 rotation; a regression target needs one of them)

Optional keys (ask with ``fields=``): ``contact_mask`` (1, H, W) bool; ``markers_ref`` (N, 2) float32,
scaled like ``markers``; ``markers_px`` (N, 2) float32 current centres in pixels; ``normal_force_n`` ()
float32 N; ``shear_force_n`` (2,) float32 N; ``slip_mm`` () float32 mm.
Every sample also carries ``sensor``, ``pad``, ``episode_id``, ``name`` (indenter shape or task: the
probe's label) as strings and ``frame``, ``dataset`` as ints.

Compact samples (``compact=True``): ``marked_rgb`` and ``pure_rgb`` stay (3, H, W) uint8 and depth comes
as ``depth_um`` (1, H, W) int16 micrometres (exact; the gels are at most 4 mm thick, far below 32.767 mm),
a quarter of the bytes. Moving float32 images from worker processes costs more than reading them (about
2.2 MB per 320 x 240 sample through shared memory; see ``benchmarks/loader_throughput.py``), so a fast
pipeline sends compact samples and calls ``to_float(batch)`` after the DataLoader, in the training
process or on the GPU; it gives exactly the float targets above.

Channels-last images (``channels_last=True``): the same shapes and values, but each (3, H, W) image is a
view of (H, W, 3) memory, as the episodes store it, and batches from ``read_batch`` (so ``FrameBatchLoader``)
are (B, 3, H, W) views of (B, H, W, 3) memory: ``torch.channels_last`` strides, what convolutions on the CPU
prefer anyway. A compact image then decodes straight into its batch slot, with no HWC -> CHW copy (0.13 ms a
sample for the two images, a seventh of one thread's CPU time); ``to_float`` keeps the layout (``.to``
preserves it).
``default_collate`` (``DataLoader(batch_size=N)``) stacks samples into contiguous memory whatever their
layout: same values, contiguous strides. Depth and masks (one channel) are contiguous either way.

The scaling choices keep the five MSE terms of similar size without dataset statistics: images in
[0, 1], depth in mm (a deep press is about 1 mm), markers in [-1, 1] whatever the resolution, and pose
translations in mm (metres would make the pose loss a thousand times smaller than the rest).

Batching: samples keep their sensor's native resolution and marker count (gelsight_mini 240 x 320 with
63 markers, gf225 480 x 480 with 81, xense_ws 240 x 320 with 220). ``default_collate`` stacks only
samples of one sensor, so a dataset that mixes sensors needs either ``sensors=`` (one loader per sensor)
or ``SensorBatchSampler`` (each batch drawn from one sensor). ``Resize`` makes images a common size but
cannot change the marker count.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch


from univtac_data.loaders.buffers import BatchBuffers
from univtac_data.loaders.episodes import EpisodeReader, EpisodeRef, FrameSource, PathLike, as_path_list, open_selected, \
    require_paths
from univtac_data.loaders.files import DEFAULT_MAX_OPEN_FILES
from univtac_data.loaders.layouts import DEFAULT_BUDGET_MIB, LayoutCache
from univtac_data.loaders.sampler import FrameTable
from univtac_data.loaders.split import Split

ENCODER_TARGETS: tuple[str, ...] = ("marked_rgb", "pure_rgb", "depth_mm", "markers", "object_pose")
"""The five targets of the UniVTAC encoder: I_marked, I_pure, D, M, p."""

# sample key -> stored array it comes from (under tactile/{pad}/)
FRAME_FIELDS: dict[str, str] = {
    "marked_rgb": "marked_rgb", "pure_rgb": "pure_rgb", "depth_mm": "depth_um", "markers": "markers_px",
    "object_pose": "object_pose", "contact_mask": "contact_mask", "markers_ref": "markers_ref_px",
    "markers_px": "markers_px", "normal_force_n": "normal_force_n", "shear_force_n": "shear_force_n",
    "slip_mm": "slip_mm",
}

# sample keys whose stored arrays are one chunk per frame, decoded straight into a buffer (chunks.py)
DECODED_FIELDS: tuple[str, ...] = ("marked_rgb", "pure_rgb", "depth_mm")
IMAGE_KEYS: tuple[str, ...] = ("marked_rgb", "pure_rgb")   # (H, W, 3) uint8 as stored, (3, H, W) as samples
IMAGE_SCALE = np.float32(1.0 / 255.0)                      # what image_chw's mul_(1.0 / 255.0) multiplies by

Sample = dict[str, Any]


@dataclass(frozen=True)
class TactileFrameConfig:
    """What a ``TactileFrameDataset`` serves. Every filter is applied before the index table is built."""

    fields: tuple[str, ...] = ENCODER_TARGETS  # sample keys to produce (keys of FRAME_FIELDS)
    sensors: tuple[str, ...] | None = None     # keep only episodes of these sensor profiles; None: all
    pads: tuple[str, ...] | None = None        # keep only these pads, e.g. ("left",); None: every pad
    names: tuple[str, ...] | None = None       # keep only these shape / task names; None: all
    episodes: tuple[str, ...] | None = None    # explicit episode ids (before the split); None: all
    split: Split = "all"                       # "train" / "val" by hash of the episode id, or "all"
    val_fraction: float = 0.1                  # share of episodes in "val"
    split_seed: int = 0                        # another seed gives another (still episode-level) split
    max_open_episodes: int = 16                # open handles kept per process (LRU)
    max_open_files: int = DEFAULT_MAX_OPEN_FILES  # plain descriptors kept per reader (per thread; LRU)
    layout_cache_mib: float = DEFAULT_BUDGET_MIB  # chunk places and small arrays kept per process (LRU); 0: none
    compact: bool = False                      # uint8 images and int16 um depth; convert with to_float(batch)
    channels_last: bool = False                # images as (3, H, W) views of (H, W, 3) memory; channels_last batches

    def __post_init__(self) -> None:
        unknown = [f for f in self.fields if f not in FRAME_FIELDS]
        if unknown or not self.fields:
            raise ValueError(f"fields must be a non-empty subset of {sorted(FRAME_FIELDS)} (got {list(self.fields)})")
        if self.max_open_episodes < 1 or self.max_open_files < 1 or not self.layout_cache_mib >= 0:
            raise ValueError(f"need max_open_episodes >= 1, max_open_files >= 1, layout_cache_mib >= 0 (got "
                             f"{self.max_open_episodes}, {self.max_open_files}, {self.layout_cache_mib})")
        for name in ("compact", "channels_last"):   # a string such as "false" would read as True
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be a bool (got {getattr(self, name)!r})")


def _tuple(value: Sequence[str] | str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    return (value,) if isinstance(value, str) else tuple(value)


class TactileFrameDataset(torch.utils.data.Dataset[Sample]):
    """Map-style dataset over (frame, pad) pairs of one or several univtac-data datasets.

    Owns the selected episode list (``episodes``), the index table (``table``, a ``FrameTable``) and an
    ``EpisodeReader`` that opens files lazily in whichever process reads (safe with DataLoader workers).
    See the module docstring for the sample's keys, shapes, units and normalisation.

    Arguments: ``path_or_paths`` one dataset or a list; ``transform`` a callable applied to each sample
    dict (in the worker); the rest as in ``TactileFrameConfig``.
    """

    def __init__(self, path_or_paths: PathLike | Sequence[PathLike], *, fields: Sequence[str] = ENCODER_TARGETS,
                 sensors: Sequence[str] | str | None = None, pads: Sequence[str] | str | None = None,
                 transform: Callable[[Sample], Sample] | None = None, episodes: Sequence[str] | None = None,
                 names: Sequence[str] | str | None = None, split: Split = "all", val_fraction: float = 0.1,
                 split_seed: int = 0, max_open_episodes: int = 16, compact: bool = False,
                 channels_last: bool = False, max_open_files: int = DEFAULT_MAX_OPEN_FILES,
                 layout_cache_mib: float = DEFAULT_BUDGET_MIB) -> None:
        config = TactileFrameConfig(fields=tuple(fields), sensors=_tuple(sensors), pads=_tuple(pads),
                                    names=_tuple(names), episodes=_tuple(episodes), split=split,
                                    val_fraction=val_fraction, split_seed=split_seed,
                                    max_open_episodes=max_open_episodes, compact=compact,
                                    channels_last=channels_last, max_open_files=max_open_files,
                                    layout_cache_mib=layout_cache_mib)
        self._setup(as_path_list(path_or_paths), config, transform)

    @classmethod
    def from_config(cls, path_or_paths: PathLike | Sequence[PathLike], config: TactileFrameConfig,
                    transform: Callable[[Sample], Sample] | None = None) -> TactileFrameDataset:
        self = cls.__new__(cls)
        self._setup(as_path_list(path_or_paths), config, transform)
        return self

    def _setup(self, paths: list[str], config: TactileFrameConfig, transform: Callable[[Sample], Sample] | None) \
            -> None:
        self.config = config
        self.transform = transform
        self.datasets, self.episodes = open_selected(paths, config)
        pads = [tuple(p for p in ref.pads if config.pads is None or p in config.pads) for ref in self.episodes]
        if not any(pads):
            raise ValueError(f"no episode has any of the pads {list(config.pads or [])}; "
                             f"pads present: {sorted({p for ref in self.episodes for p in ref.pads})}")
        for ref, ep_pads in zip(self.episodes, pads):
            require_paths([ref], [f"tactile/{pad}/{FRAME_FIELDS[f]}" for pad in ep_pads for f in config.fields],
                          self.datasets)
        self.table = FrameTable([ref.n_frames for ref in self.episodes], pads)
        self.reader = EpisodeReader(self.datasets, max_open=config.max_open_episodes,
                                    max_open_files=config.max_open_files,
                                    layouts=LayoutCache(int(config.layout_cache_mib * 2**20)))
        self._sizes = {ref.sensor: self.datasets[ref.dataset].sensor(ref.sensor) for ref in self.episodes}

    def __len__(self) -> int:
        return len(self.table)

    @property
    def names(self) -> list[str]:
        """Distinct shape / task names of the selected episodes, sorted (class labels for a probe)."""
        return sorted({ref.name for ref in self.episodes})

    @property
    def sensors(self) -> list[str]:
        """Distinct sensor profiles of the selected episodes, sorted."""
        return sorted(self._sizes)

    def sensor_of(self, index: int) -> str:
        """Sensor profile of sample ``index`` (no I/O; used by ``SensorBatchSampler``)."""
        return self.episodes[int(self.table.episode[index])].sensor

    def _row(self, index: int) -> tuple[EpisodeRef, int, str]:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} samples")
        episode, frame, pad = self.table.row(index % len(self))
        return self.episodes[episode], frame, pad

    def read_raw(self, index: int) -> tuple[EpisodeRef, int, str, dict[str, np.ndarray]]:
        """``(episode, frame, pad, arrays)``: the stored arrays of sample ``index`` before conversion."""
        ref, frame, pad = self._row(index)
        with self.reader.holding():
            return ref, frame, pad, read_fields(self.reader, ref, frame, pad, self.config.fields)

    def read_batch(self, indices: Sequence[int], reader: EpisodeReader | None = None,
                   buffers: BatchBuffers | None = None) -> Sample:
        """Samples ``indices`` as one batch: exactly ``default_collate([self[i] for i in indices])``, but images
        and depth are decoded straight into the batch tensors (no per-sample tensors, no stacking copy).
        With ``channels_last`` the images are (B, 3, H, W) views of (B, H, W, 3) memory (``torch.channels_last``
        strides), where ``default_collate`` stacks into contiguous memory: same shapes and values.

        Inside a DataLoader worker the batch tensors are allocated in shared memory, as ``default_collate``
        does, so sending the batch copies nothing. ``reader``: the ``EpisodeReader`` to read through (one
        per thread; ``FrameBatchLoader`` passes its own); default ``self.reader``. It keeps every episode of
        the batch open until the batch is read, however many (``max_open_episodes`` bounds what stays open
        between batches: below the episodes a batch spans, files are reopened every batch). With a ``transform``, or
        samples of several sensors, this is ``default_collate`` of single samples. ``buffers``: where the
        image and depth tensors go (``FrameBatchLoader`` reuses memory this way); default new tensors.
        """
        reader = self.reader if reader is None else reader
        with reader.holding():   # sources are taken for all rows before any is read
            return self._read_batch(indices, reader, buffers)

    def _read_batch(self, indices: Sequence[int], reader: EpisodeReader, buffers: BatchBuffers | None) -> Sample:
        rows = [self._row(int(i)) for i in indices]
        if self.transform is not None or len({ref.sensor for ref, _, _ in rows}) != 1:
            collated = torch.utils.data.default_collate([self._sample(int(i), reader) for i in indices])
            return images_channels_last(collated) if self.config.channels_last else collated
        profile = self._sizes[rows[0][0].sensor]
        width, height = profile.image_width_px, profile.image_height_px
        convert = convert_compact if self.config.compact else convert_target
        compact, channels_last = self.config.compact, self.config.channels_last
        decoded: dict[str, tuple[str, torch.Tensor]] = {}   # field key -> (batch key, tensor)
        # I_marked is stored as a residual of I_pure: decode I_pure first and add its frames to the marked
        # residuals rather than decode each I_pure frame twice (about 40 % of a compact sample's CPU in one
        # thread when measured; benchmarks/loader_throughput.py)
        fields = list(self.config.fields)
        # sources in field order: a damaged file fails on the same array as a single sample's read
        field_sources = {key: [(reader.frame_source(ref, f"tactile/{pad}/{FRAME_FIELDS[key]}"), frame)
                               for ref, frame, pad in rows] for key in fields if key in DECODED_FIELDS}
        # only on the chunk fast path: other reads go through the backend, which reuses the base frame itself
        share_pure = "marked_rgb" in fields and "pure_rgb" in fields and all(
            source.chunks is not None for source, _ in field_sources["marked_rgb"])
        pure_frames: np.ndarray | None = None
        pure_sources: list[FrameSource] = []
        for key in sorted(fields, key=lambda k: k != "pure_rgb") if share_pure else fields:
            if key in field_sources:
                sources = field_sources[key]
                if share_pure and key == "pure_rgb":
                    pure_sources = [source for source, _ in sources]
                    images, pure_frames = decode_images(sources, compact, channels_last, buffers, keep_frames=True)
                    decoded[key] = (key, images)
                elif share_pure and key == "marked_rgb" and pure_frames is not None:
                    bases = [pure_frames[k] if source.base is pure_sources[k] else None
                             for k, (source, _) in enumerate(sources)]
                    decoded[key] = (key, decode_images(sources, compact, channels_last, buffers, bases=bases)[0])
                else:
                    decoded[key] = decode_batch(key, sources, compact, buffers, channels_last)
            else:
                samples = [convert(key, value, width, height, channels_last) for value in
                           (read_fields(reader, ref, frame, pad, (key,))[key] for ref, frame, pad in rows)]
                decoded[key] = (key, torch.stack([tensor for _, tensor in samples]))
        batch: Sample = dict(decoded[key] for key in fields)
        batch.update(sensor=[ref.sensor for ref, _, _ in rows], pad=[pad for _, _, pad in rows],
                     episode_id=[ref.episode_id for ref, _, _ in rows], name=[ref.name for ref, _, _ in rows],
                     frame=torch.tensor([frame for _, frame, _ in rows]),
                     dataset=torch.tensor([ref.dataset for ref, _, _ in rows]))
        return batch

    def __getitem__(self, index: int | Sequence[int]) -> Sample:
        if isinstance(index, (list, tuple, range, np.ndarray)):
            return self.read_batch(index)   # a list from a batch sampler: DataLoader(batch_size=None, ...)
        with self.reader.holding():   # one check of the episode's file for all the sample's arrays
            return self._sample(index, self.reader)

    def _sample(self, index: int, reader: EpisodeReader) -> Sample:
        ref, frame, pad = self._row(index)
        profile = self._sizes[ref.sensor]
        convert = convert_compact if self.config.compact else convert_target
        sample: Sample = {}
        for key, value in read_fields(reader, ref, frame, pad, self.config.fields).items():
            name, tensor = convert(key, value, profile.image_width_px, profile.image_height_px,
                                   self.config.channels_last)
            sample[name] = tensor
        sample.update(sensor=ref.sensor, pad=pad, episode_id=ref.episode_id, name=ref.name, frame=frame,
                      dataset=ref.dataset)
        return self.transform(sample) if self.transform is not None else sample


def read_fields(reader: EpisodeReader, ref: EpisodeRef, frame: int, pad: str, fields: Sequence[str]) \
        -> dict[str, np.ndarray]:
    """The stored arrays of one (frame, pad) for sample keys ``fields``, before conversion."""
    arrays = {}
    for key in fields:
        path = f"tactile/{pad}/{FRAME_FIELDS[key]}"
        if key in DECODED_FIELDS:
            arrays[key] = reader.frame_source(ref, path).read(frame)
        elif key == "markers_ref":
            arrays[key] = reader.read(ref, path)
        else:
            arrays[key] = reader.read(ref, path, frame)
    return arrays


def decode_batch(key: str, sources: Sequence[tuple[FrameSource, int]], compact: bool,
                 buffers: BatchBuffers | None = None, channels_last: bool = False) -> tuple[str, torch.Tensor]:
    """``(sample key, (B, C, H, W) tensor)`` for an image or depth key, each ``(source, frame)`` decoded into
    its slot; values exactly those of ``convert_target`` / ``convert_compact`` on the frame."""
    if key in IMAGE_KEYS:
        return key, decode_images(sources, compact, channels_last, buffers)[0]
    if compact:
        return "depth_um", decode_depth_um(sources, buffers)
    return key, decode_depth_mm(sources, buffers)


def decode_images(sources: Sequence[tuple[FrameSource, int]], compact: bool, channels_last: bool,
                  buffers: BatchBuffers | None = None, *, keep_frames: bool = False,
                  bases: Sequence[np.ndarray | None] | None = None) -> tuple[torch.Tensor, np.ndarray | None]:
    """``(images, frames)``: (B, 3, H, W) uint8 (``compact``) or float32 / 255 images, frame k of the batch
    from ``sources[k]``, contiguous, or with ``channels_last`` a view of (B, H, W, 3) memory; and with
    ``keep_frames`` the (B, H, W, 3) uint8 frames as stored (the batch's own memory when compact and
    channels-last), else ``None``. ``bases[k]``: the already decoded base frame of a residual source
    (``FrameSource.read_into``), or ``None`` to decode it.

    Copies run in NumPy, in this thread: torch's may spin OpenMP threads on a busy machine.
    """
    height, width, _ = sources[0][0].frame_shape
    dtype = torch.uint8 if compact else torch.float32
    in_place = compact and channels_last   # the batch's memory holds the stored frames themselves
    frames = np.empty((len(sources), height, width, 3), np.uint8) if keep_frames and not in_place else None

    def stored_frame(k: int, into: np.ndarray) -> np.ndarray:
        source, frame = sources[k]
        base = None if bases is None else bases[k]
        if base is None:
            source.read_into(frame, into)
        else:
            source.read_into(frame, into, base_values=base)
        return into

    if channels_last:
        out = batch_tensor((len(sources), height, width, 3), dtype, buffers)
        hwc = out.numpy()
        if in_place:   # each slot is a stored frame's exact layout: decode straight into the batch
            for k in range(len(sources)):
                stored_frame(k, hwc[k])
            return out.permute(0, 3, 1, 2), (hwc if keep_frames else None)
        scratch = np.empty((height, width, 3), np.uint8)   # reused for every frame
        for k in range(len(sources)):
            image = stored_frame(k, frames[k] if frames is not None else scratch)
            np.multiply(image, IMAGE_SCALE, out=hwc[k], dtype=np.float32)
        return out.permute(0, 3, 1, 2), frames
    out = batch_tensor((len(sources), 3, height, width), dtype, buffers)
    chw = out.numpy()
    scratch = np.empty((height, width, 3), np.uint8)   # (H, W, 3) as stored; reused for every frame
    for k in range(len(sources)):
        image = stored_frame(k, frames[k] if frames is not None else scratch)
        # strided reads, contiguous writes: writing through a transposed view is 1.6x slower for float32
        if compact:
            np.copyto(chw[k], image.transpose(2, 0, 1))
        else:
            np.multiply(image.transpose(2, 0, 1), IMAGE_SCALE, out=chw[k], dtype=np.float32)
    return out, frames


def decode_depth_um(sources: Sequence[tuple[FrameSource, int]], buffers: BatchBuffers | None = None) \
        -> torch.Tensor:
    """(B, 1, H, W) int16 micrometres, frame k from ``sources[k]``; raises when a depth exceeds int16."""
    height, width = sources[0][0].frame_shape
    out = batch_tensor((len(sources), 1, height, width), torch.int16, buffers)
    depth = out.numpy()
    for k, (source, frame) in enumerate(sources):
        source.read_into(frame, depth[k, 0])   # uint16 um bits; above 32767 they read negative
    if len(sources) and int(depth.min()) < 0:   # one reduction, no temporary mask
        depth_max = int(depth.view(np.uint16).max())
        raise ValueError(f"depth {depth_max} um exceeds the compact int16 range ({DEPTH_UM_MAX} um); "
                         "use compact=False")
    return out


def decode_depth_mm(sources: Sequence[tuple[FrameSource, int]], buffers: BatchBuffers | None = None) \
        -> torch.Tensor:
    """(B, 1, H, W) float32 millimetres (stored um / 1000), frame k from ``sources[k]``."""
    first = sources[0][0]
    height, width = first.frame_shape
    out = batch_tensor((len(sources), 1, height, width), torch.float32, buffers)
    depth = out.numpy()
    scratch_um = np.empty(first.frame_shape, first.dtype)
    for k, (source, frame) in enumerate(sources):
        source.read_into(frame, scratch_um)
        np.multiply(scratch_um, np.float32(1e-3), out=depth[k, 0], dtype=np.float32)
    return out


def batch_tensor(shape: tuple[int, ...], dtype: torch.dtype, buffers: BatchBuffers | None = None) -> torch.Tensor:
    """An uninitialised tensor for a batch: from ``buffers`` when given; in shared memory inside a
    DataLoader worker (what ``default_collate`` does there), so that sending it copies nothing."""
    if buffers is not None:
        return buffers.empty(shape, dtype)
    if torch.utils.data.get_worker_info() is None:
        return torch.empty(shape, dtype=dtype)
    nbytes = int(np.prod(shape)) * torch.empty((), dtype=dtype).element_size()
    return torch.empty(0, dtype=dtype).set_(torch.UntypedStorage._new_shared(nbytes), 0, shape)


def image_chw(rgb: np.ndarray) -> torch.Tensor:
    """(H, W, 3) uint8 -> (3, H, W) float32 in [0, 1], contiguous."""
    hwc = torch.from_numpy(np.ascontiguousarray(rgb))
    out = torch.empty((3, rgb.shape[0], rgb.shape[1]), dtype=torch.float32)
    out.copy_(hwc.permute(2, 0, 1))
    return out.mul_(1.0 / 255.0)


def image_tensor(rgb: np.ndarray, compact: bool, channels_last: bool) -> torch.Tensor:
    """(H, W, 3) uint8 -> (3, H, W) uint8 (``compact``) or float32 / 255: contiguous, or with
    ``channels_last`` a view of (H, W, 3) memory (for a compact image, ``rgb``'s own when it is writable)."""
    if not channels_last:
        return torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))) if compact else image_chw(rgb)
    if compact:
        hwc = np.require(rgb, np.uint8, ("C", "W"))
    else:   # float32(value) * float32(1 / 255), bit for bit what image_chw computes
        hwc = np.multiply(rgb, IMAGE_SCALE, dtype=np.float32)
    return torch.from_numpy(hwc).permute(2, 0, 1)


def scale_markers(markers_px: np.ndarray, width: int, height: int) -> torch.Tensor:
    """(N, 2) pixel centres (u, v) -> (N, 2) float32 in [-1, 1] (``2 u / (W - 1) - 1``)."""
    scale = np.array([2.0 / (width - 1), 2.0 / (height - 1)], np.float32)
    return torch.from_numpy(markers_px.astype(np.float32) * scale - 1.0)


def convert_target(key: str, value: np.ndarray, width: int, height: int, channels_last: bool = False) \
        -> tuple[str, torch.Tensor]:
    """A stored array of one frame -> ``(sample key, tensor)`` (see the module docstring)."""
    if key in IMAGE_KEYS:
        return key, image_tensor(value, compact=False, channels_last=channels_last)
    if key == "depth_mm":
        return key, torch.from_numpy(value.astype(np.float32) * np.float32(1e-3))[None]
    if key in ("markers", "markers_ref"):
        return key, scale_markers(value, width, height)
    if key == "object_pose":
        pose = value.astype(np.float32)
        pose[:3] *= 1000.0
        if pose[3] < 0:
            pose[3:] = -pose[3:]
        return key, torch.from_numpy(pose)
    if key == "contact_mask":
        return key, torch.from_numpy(np.ascontiguousarray(value, dtype=bool))[None]
    return key, torch.from_numpy(np.asarray(value, np.float32).copy())


DEPTH_UM_MAX = 32767  # int16 range; the gels are at most 4 mm thick


def convert_compact(key: str, value: np.ndarray, width: int, height: int, channels_last: bool = False) \
        -> tuple[str, torch.Tensor]:
    """Like ``convert_target``, but images stay (3, H, W) uint8 and depth is ``depth_um`` (1, H, W) int16."""
    if key in IMAGE_KEYS:
        return key, image_tensor(value, compact=True, channels_last=channels_last)
    if key == "depth_mm":
        if value.size and int(value.max()) > DEPTH_UM_MAX:
            raise ValueError(f"depth {int(value.max())} um exceeds the compact int16 range ({DEPTH_UM_MAX} um); "
                             "use compact=False")
        return "depth_um", torch.from_numpy(value.astype(np.int16))[None]
    return convert_target(key, value, width, height, channels_last)


def images_channels_last(batch: Sample) -> Sample:
    """``batch`` with its (B, 3, H, W) images in ``torch.channels_last`` memory (a copy unless already)."""
    out = dict(batch)
    for key in IMAGE_KEYS:
        if isinstance(out.get(key), torch.Tensor) and out[key].ndim == 4:
            out[key] = out[key].contiguous(memory_format=torch.channels_last)
    return out


def to_float(batch: Sample) -> Sample:
    """Compact samples or batches -> the float targets: uint8 ``marked_rgb``/``pure_rgb`` (..., 3, H, W) to
    float32 / 255; int16 ``depth_um`` (..., 1, H, W) to float32 ``depth_mm``. Other keys pass through.
    Works on any device (call it after moving the batch to the GPU); channels-last images stay channels-last
    (``.to`` preserves the memory format)."""
    out = dict(batch)
    for key in IMAGE_KEYS:
        if key in out and out[key].dtype == torch.uint8:
            out[key] = out[key].to(torch.float32).mul_(1.0 / 255.0)
    if "depth_um" in out:
        out["depth_mm"] = out.pop("depth_um").to(torch.float32).mul_(1e-3)
    return out
