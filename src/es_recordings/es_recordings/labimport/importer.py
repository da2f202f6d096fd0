"""Import a lab recording into a contract bag, streaming it in chunks of samples.

The bag is written into a temporary directory beside the target and renamed to it only
when every topic went through, so a failed import leaves nothing behind. Samples with a
non-finite value or time stamp are dropped and counted (per topic, with the number of runs
they form); every other problem is a :class:`LabImportError` with one readable line.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from es_msgs_py.bag import FLOAT64_MULTI_ARRAY, BagError, BagWriter, encode_float64_multi_array
from es_recordings.labimport.errors import LabImportError, SourceError
from es_recordings.labimport.mapfile import ImportMap
from es_recordings.labimport.plan import TopicPlan, plan_import
from es_recordings.labimport.recording import FloatArray, Source
from es_recordings.labimport.sources import open_source

#: Bytes of messages encoded per chunk: the import's working set is a few times this.
CHUNK_BYTES: Final = 1 << 22


@dataclass
class TopicSummary:
    """What one topic of an import wrote and dropped (times in s)."""

    topic: str
    source: str
    unit: str
    messages: int = 0
    dropped: int = 0
    runs: int = 0
    first_s: float = float("nan")
    last_s: float = float("nan")

    def line(self) -> str:
        """Return one line of the import summary."""
        text = (f"{self.topic}: {self.messages} messages from {self.source} [{self.unit}], "
                f"{self.first_s:.6g} to {self.last_s:.6g} s")
        if self.dropped:
            text += (f"; dropped {self.dropped} sample(s) with NaN/inf in {self.runs} run(s)")
        return text


@dataclass
class ImportSummary:
    """The result of an import: the bag written and one summary per topic."""

    bag: Path
    storage: str
    topics: list[TopicSummary]

    def lines(self) -> list[str]:
        """Return the summary as lines of text."""
        return [f"wrote {self.bag} ({self.storage})", *(t.line() for t in self.topics)]


class _Stamps:
    """Turns a plan's time base into checked nanosecond stamps, chunk by chunk."""

    def __init__(self, plan: TopicPlan, where: str) -> None:
        self.plan = plan
        self.where = where
        self.last_ns: int | None = None
        self.last_s = float("nan")

    def seconds(self, block: FloatArray | None, start: int, stop: int) -> FloatArray:
        time = self.plan.time
        if block is not None:
            return block.reshape(-1) * time.scale
        assert time.rate is not None
        return time.start + np.arange(start, stop, dtype=np.float64) / time.rate

    def check(self, seconds: FloatArray, index: np.ndarray) -> np.ndarray:
        """Return the stamps (ns) of the kept samples; raise on a bad time base."""
        name = self.plan.time.variable or "of the map"
        if seconds.size and seconds.min() < 0:
            i = int(np.argmax(seconds < 0))
            raise SourceError(f"{self.where}: time {name} is negative at sample {index[i]} "
                              f"({seconds[i]:.9g} s); bag time stamps start at 0")
        ns = np.round(seconds * 1e9).astype(np.int64)
        previous = np.concatenate(([self.last_ns], ns[:-1])) if self.last_ns is not None else (
            ns[:-1])
        current = ns if self.last_ns is not None else ns[1:]
        bad = np.flatnonzero(current <= previous)
        if bad.size:
            i = int(bad[0]) + (0 if self.last_ns is not None else 1)
            before = (self.last_s if i == 0 else float(seconds[i - 1]))
            raise SourceError(
                f"{self.where}: time {name} is not increasing at sample {index[i]} "
                f"({seconds[i]:.9g} s after {before:.9g} s)"
            )
        if ns.size:
            self.last_ns = int(ns[-1])
            self.last_s = float(seconds[-1])
        return ns


def _write_topic(source: Source, plan: TopicPlan, bag: BagWriter) -> TopicSummary:
    entry = plan.entry
    unit = entry.to_si()
    summary = TopicSummary(entry.topic, plan.source_text, entry.unit)
    stamps = _Stamps(plan, f"{source.path}: {entry.topic}")
    template = encode_float64_multi_array(np.zeros(entry.shape), entry.kind)
    header = np.frombuffer(template[: len(template) - 8 * entry.size], dtype=np.uint8)
    bag.add_topic(entry.topic, FLOAT64_MULTI_ARRAY)
    names = list(plan.names)
    axes = list(plan.axes)
    if plan.time.variable is not None:
        names.append(plan.time.variable)
        axes.append(plan.time_axis)
    step = max(1, CHUNK_BYTES // (header.size + 8 * entry.size))
    previous_bad = False
    for start in range(0, plan.samples, step):
        stop = min(start + step, plan.samples)
        arrays = source.read(names, axes, start, stop)
        time_block = arrays.pop() if plan.time.variable is not None else None
        data = arrays[0] if len(arrays) == 1 else np.stack(arrays, axis=1)
        values = plan.layout(data) * unit.scale + unit.offset
        seconds = stamps.seconds(time_block, start, stop)
        good = np.isfinite(values.reshape(len(values), -1)).all(axis=1) & np.isfinite(seconds)
        bad = ~good
        summary.dropped += int(bad.sum())
        summary.runs += int((bad & ~np.concatenate(([previous_bad], bad[:-1]))).sum())
        previous_bad = bool(bad[-1])
        index = np.flatnonzero(good) + start
        ns = stamps.check(seconds[good], index)
        kept = np.ascontiguousarray(values[good], dtype="<f8").reshape(len(ns), entry.size)
        payloads = np.empty((len(ns), header.size + 8 * entry.size), dtype=np.uint8)
        payloads[:, : header.size] = header
        payloads[:, header.size :] = kept.view(np.uint8)
        for stamp, payload in zip(ns.tolist(), payloads, strict=True):
            bag.write(entry.topic, stamp, payload.tobytes(), FLOAT64_MULTI_ARRAY)
        if len(ns):
            if summary.messages == 0:
                summary.first_s = float(seconds[good][0])
            summary.messages += len(ns)
    if summary.messages == 0:
        raise SourceError(
            f"{source.path}: {entry.topic}: no usable samples ({plan.samples} in the recording, "
            f"{summary.dropped} with NaN/inf)"
        )
    summary.last_s = stamps.last_s
    return summary


def import_recording(
    recording: str | Path, bag: str | Path, import_map: ImportMap, storage: str = "mcap"
) -> ImportSummary:
    """Import ``recording`` into a new contract bag ``bag`` as ``import_map`` says.

    Args:
        recording: a .mat, .h5/.hdf5, .csv/.tsv or .npz file.
        bag: the bag directory to create (must not exist).
        import_map: the validated map (:func:`es_recordings.labimport.mapfile.load_map`).
        storage: ``"mcap"`` (default) or ``"sqlite3"``.

    Raises:
        LabImportError: the recording, the map or the target is unusable (one line); nothing
            is left at ``bag`` then.

    """
    target = Path(bag)
    if target.exists() or target.is_symlink():
        raise LabImportError(f"{target} exists already; a bag is never overwritten")
    source = open_source(recording)
    try:
        plans = plan_import(source, import_map)
        new_parents = [p for p in reversed(target.absolute().parents) if not p.exists()]
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            work = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".importing",
                                         dir=target.parent))
        except OSError as err:
            raise LabImportError(f"cannot create {target}: {err.strerror or err}") from None
        done = False
        try:
            with BagWriter(work / target.name, storage) as writer:
                topics = [_write_topic(source, plan, writer) for plan in plans]
            os.rename(work / target.name, target)
            done = True
        except BagError as err:
            raise LabImportError(str(err)) from None
        except OSError as err:
            raise LabImportError(f"cannot write {target}: {err.strerror or err}") from None
        finally:
            shutil.rmtree(work, ignore_errors=True)
            for parent in [] if done else reversed(new_parents):
                with suppress(OSError):
                    parent.rmdir()  # created for this bag, empty again
    finally:
        source.close()
    return ImportSummary(target, storage, topics)
