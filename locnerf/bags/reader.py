"""Open a rosbag2 (a folder with metadata.yaml, or one .mcap / .db3 file) with rosbags, and describe it.

rosbags reads both storages (MCAP and SQLite3). Every failure to read is a :class:`DatasetError`
naming the bag and what was expected: a missing or unrecognised file, a file cut short (an MCAP
file without its end magic, a SQLite file whose pages are missing), a storage error while reading.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from rosbags.rosbag2 import Reader

from locnerf.errors import DatasetError

STORAGES = {".mcap": "mcap", ".db3": "sqlite3"}
"""Storage file suffix -> rosbag2 storage identifier."""


def is_bag(path: str | Path) -> bool:
    """A rosbag2 folder (holding metadata.yaml) or an .mcap / .db3 file."""
    path = Path(path)
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or (path.is_file() and path.suffix in STORAGES)


def _unreadable(path: Path, error: Exception, where: str) -> DatasetError:
    return DatasetError(
        f"bag {path}: {where} ({type(error).__name__}: {error}); expected a complete rosbag2 (MCAP or SQLite3) - "
        "a recording cut off before it was closed can be repaired with `mcap recover` (MCAP) or `ros2 bag reindex`"
    )


@contextlib.contextmanager
def open_bag(path: str | Path) -> Iterator[Reader]:
    """An open rosbags ``Reader`` of ``path``.

    Raises:
        FileNotFoundError: no such file or folder.
        DatasetError: not a bag, or a bag rosbags cannot open (truncated, corrupt).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag {path}: no such file or folder (expected a rosbag2 folder or an .mcap / .db3 file)")
    try:
        reader = Reader(path)
        reader.open()
    except FileNotFoundError as error:
        raise DatasetError(f"bag {path}: {error} (expected a rosbag2 folder with metadata.yaml and its storage files)") from None
    except Exception as error:  # noqa: BLE001 - rosbags' storage plugins raise their own errors (ReaderError, sqlite3, zstd, yaml)
        raise _unreadable(path, error, "cannot be opened") from None
    try:
        yield reader
    finally:
        reader.close()


def topic_types(reader: Reader) -> dict[str, str]:
    """Topic -> ROS type of every connection of the bag."""
    return {connection.topic: connection.msgtype for connection in reader.connections}


def raw_messages(reader: Reader, topics: Iterable[str]) -> Iterator[tuple[str, int, bytes]]:
    """(topic, bag time ns, CDR bytes) of ``topics``, in bag-time order.

    Raises:
        DatasetError: the storage fails part way (a damaged chunk or page), naming the bag time reached.
    """
    wanted = set(topics)
    connections = [connection for connection in reader.connections if connection.topic in wanted]
    last = None
    try:
        for connection, timestamp, data in reader.messages(connections=connections):
            last = timestamp
            yield connection.topic, timestamp, bytes(data)
    except Exception as error:  # noqa: BLE001 - see open_bag
        where = "reading failed" + ("" if last is None else f" after bag time {last} ns")
        raise _unreadable(Path(reader.path), error, where) from None


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: its type, message count, first and last bag times (ns) and mean rate (Hz)."""

    topic: str
    msgtype: str
    count: int
    first_ns: int | None
    last_ns: int | None

    @property
    def rate_hz(self) -> float:
        """(count - 1) / span; NaN with fewer than two messages or a zero span."""
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns == self.first_ns:
            return math.nan
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)


def storage_of(path: Path) -> str:
    """``mcap`` or ``sqlite3``: the storage of a bag file or of the first storage file in a bag folder."""
    files = [path] if path.is_file() else sorted(path.iterdir())
    return next((STORAGES[file.suffix] for file in files if file.suffix in STORAGES), "unknown")


def summarize(path: str | Path) -> tuple[str, list[TopicSummary]]:
    """The bag's storage and, per topic, type, count, time span and rate (reading every message's time).

    Raises:
        as :func:`open_bag` and :func:`raw_messages`.
    """
    with open_bag(path) as reader:
        types = topic_types(reader)
        counts = dict.fromkeys(types, 0)
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        for topic, stamp, _data in raw_messages(reader, types):
            counts[topic] += 1
            first.setdefault(topic, stamp)
            last[topic] = stamp
    return storage_of(Path(path)), [TopicSummary(topic, types[topic], counts[topic], first.get(topic), last.get(topic)) for topic in sorted(types)]


def bag_extent(path: str | Path) -> tuple[float, int]:
    """(bag-time span in seconds, message count) from the bag's index, without reading its messages."""
    with open_bag(path) as reader:
        return reader.duration * 1e-9, reader.message_count
