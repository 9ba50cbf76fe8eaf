"""Writing and reading rosbag2 bags with rosbags (no rclpy), with clear errors.

``BagWriter`` writes serialized CDR messages (raw bytes, e.g. from an rclpy raw subscription,
or rosbags message objects it serializes) to an MCAP (default) or sqlite3 rosbag2 bag, metadata
version 9 (the format of ROS 2 Jazzy's rosbag2). ``BagReader`` opens a bag and yields
``(topic, time_ns, raw)`` or deserialized messages; every failure of the underlying library
(missing, damaged, truncated or never-closed bag) becomes a ``BagError`` that says what was
wrong and what to do.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

from .errors import BagContentError, BagNotFoundError, BagReadError, BagWriteError
from .topics import KNOWN_TOPICS, TopicQos, canonical
from .types import require_type, typestore

STORAGE_IDS = ('mcap', 'sqlite3')


class BagWriter:
    """A rosbag2 bag being written. Use as a context manager, or ``open()`` / ``close()``.

    path: the bag folder to create (must not exist); storage: 'mcap' or 'sqlite3'. Timestamps
    are the bag's receive times [ns since the epoch]. ``close()`` writes the index and
    metadata.yaml: a bag not closed (process killed) cannot be read.
    """

    def __init__(self, path: Path | str, storage: str = 'mcap', *, custom_data: dict | None = None):
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
        self.path = Path(path)
        if storage not in STORAGE_IDS:
            raise BagWriteError(f'storage {storage!r} is not supported; use one of {STORAGE_IDS}')
        if self.path.exists():
            raise BagWriteError(f'{self.path} exists already; a bag is written to a new folder: '
                                f'choose another --out or remove the old one')
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        try:
            self._writer = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        except WriterError as exc:
            raise BagWriteError(f'cannot write bag {self.path}: {exc}') from None
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(str(key), str(value))
        self._store = typestore()
        self._connections: dict[str, object] = {}
        self._msgtypes: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.is_open = False

    # -- lifecycle ---------------------------------------------------------------------------------
    def open(self) -> 'BagWriter':
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer.open()
        except Exception as exc:  # rosbags WriterError, OSError
            raise BagWriteError(f'cannot create bag {self.path}: {exc}') from None
        self.is_open = True
        return self

    def close(self) -> None:
        """Write the index and metadata.yaml; idempotent."""
        if self.is_open:
            self.is_open = False
            self._writer.close()

    def abort(self) -> None:
        """Stop without writing an index (the bag stays unreadable); for error paths."""
        if self.is_open:
            self.is_open = False
            self._writer.abort()

    def __enter__(self) -> 'BagWriter':
        return self.open()

    def __exit__(self, exc_type, exc, tb):
        # Close on success and on Ctrl-C alike, so what was written stays readable.
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        else:
            try:
                self.close()
            except Exception:
                self.abort()
        return False

    # -- writing -----------------------------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str | None = None,
                  qos: TopicQos | Iterable | None = None) -> None:
        """Declare a topic: type 'pkg/msg/Type' (default: the graph's type of a known topic),
        offered QoS as a ``TopicQos``, a list of rosbags ``Qos`` (one per publisher), or None
        (the graph's default for a known topic, else none)."""
        if not self.is_open:
            raise BagWriteError(f'bag {self.path} is not open: call open() first')
        if topic in self._connections:
            raise BagWriteError(f'topic {topic} was already added to bag {self.path}')
        spec = KNOWN_TOPICS.get(canonical(topic))
        if msgtype is None:
            if spec is None:
                raise BagWriteError(f'topic {topic} is not a graph topic: give its message type')
            msgtype = spec.msgtype
        require_type(msgtype, self._store)
        if qos is None:
            qos = spec.qos if spec is not None and spec.msgtype == msgtype else None
        profiles = ([] if qos is None else [qos.to_rosbags()] if isinstance(qos, TopicQos)
                    else list(qos))
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._store, offered_qos_profiles=profiles)
        self._msgtypes[topic] = msgtype
        self.counts[topic] = 0

    def write_raw(self, topic: str, time_ns: int, data: bytes) -> None:
        """Append serialized CDR bytes received on ``topic`` at ``time_ns`` [ns since the epoch]."""
        try:
            connection = self._connections[topic]
        except KeyError:
            raise BagWriteError(f'topic {topic} was not added to bag {self.path}: '
                                f'call add_topic() first') from None
        self._writer.write(connection, int(time_ns), data)
        self.counts[topic] += 1

    def write(self, topic: str, time_ns: int, msg) -> None:
        """Serialize a rosbags message object (see ``message()``) and append it."""
        self.write_raw(topic, time_ns, bytes(self._store.serialize_cdr(msg, self._msgtypes[topic])))

    def message(self, msgtype: str, **fields):
        """A rosbags message object of ``msgtype`` (fields as keyword arguments)."""
        return self._store.types[msgtype](**fields)


@dataclass(frozen=True)
class TopicInfo:
    """A topic in a bag: name, type, message count and the QoS profiles its publishers offered."""

    name: str
    msgtype: str
    count: int
    qos: tuple


def _not_found(path: Path) -> BagNotFoundError:
    return BagNotFoundError(f'bag {path} does not exist: give the bag folder written by '
                            f'`wind-shaper record` or `ros2 bag record` (the one holding metadata.yaml)')


class BagReader:
    """A rosbag2 bag opened for reading (folder with metadata.yaml, or a single .mcap/.db3 file).

    Use as a context manager. ``topics`` lists what the bag holds; ``messages()`` yields
    ``(topic, time_ns, raw CDR bytes)`` in time order, ``decoded()`` the same with rosbags
    message objects. Every problem is a ``BagError`` with the cause and what to do.
    """

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self._reader = None

    def open(self) -> 'BagReader':
        from rosbags.rosbag2 import Reader
        path = self.path
        if not path.exists():
            raise _not_found(path)
        if path.is_dir() and not (path / 'metadata.yaml').exists():
            stray = sorted(p.name for p in path.glob('*.mcap')) + sorted(p.name for p in path.glob('*.db3'))
            if stray:
                raise BagReadError(
                    f'bag {path} has no metadata.yaml next to {", ".join(stray)}: the recorder was '
                    f'stopped without closing the bag (killed, or the machine went down), so its index '
                    f'is missing. Stop `wind-shaper record` with Ctrl-C or --duration; the messages '
                    f'of this one may be salvaged with `mcap recover` (MCAP CLI) or `ros2 bag reindex`')
            raise BagNotFoundError(f'{path} is a folder but not a rosbag2 bag (no metadata.yaml): give '
                                   f'the bag folder written by `wind-shaper record`')
        try:
            self._reader = Reader(path)
            self._reader.open()
        except FileNotFoundError:
            raise _not_found(path) from None
        except Exception as exc:  # rosbags ReaderError, struct/YAML/OS errors of a damaged file
            self._reader = None
            raise self._damaged(exc) from None
        return self

    def _damaged(self, exc: Exception) -> BagReadError:
        cause = ' '.join(str(exc).split()).rstrip('.')  # one line, even for a YAML error
        return BagReadError(
            f'cannot read bag {self.path}: {type(exc).__name__}: {cause}. The bag is damaged or '
            f'truncated (copied while being written, disk full, recorder killed); record it '
            f'again, or try `ros2 bag reindex` / `mcap recover` on a copy')

    def close(self) -> None:
        if self._reader is not None:
            reader, self._reader = self._reader, None
            try:
                reader.close()
            except Exception:
                pass

    def __enter__(self) -> 'BagReader':
        return self.open()

    def __exit__(self, *exc):
        self.close()
        return False

    def _open_reader(self):
        if self._reader is None:
            raise BagReadError(f'bag {self.path} is not open: use `with BagReader(path) as bag:`')
        return self._reader

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topic name -> TopicInfo, in the bag's order."""
        out = {}
        for c in self._open_reader().connections:
            prev = out.get(c.topic)
            qos = tuple(getattr(c.ext, 'offered_qos_profiles', ()) or ())
            out[c.topic] = TopicInfo(c.topic, c.msgtype, c.msgcount + (prev.count if prev else 0),
                                     (prev.qos if prev else ()) + qos)
        return out

    @property
    def start_ns(self) -> int:
        return int(self._open_reader().start_time)

    @property
    def duration_s(self) -> float:
        return self._open_reader().duration * 1e-9

    @property
    def message_count(self) -> int:
        return int(self._open_reader().message_count)

    def require_topics(self, needed: Iterable[str], why: str) -> None:
        """Raise BagContentError unless every ``needed`` topic has messages in the bag."""
        have = {name: info.count for name, info in self.topics.items()}
        missing = [t for t in needed if not have.get(t)]
        if missing:
            present = ', '.join(f'{t} ({n})' for t, n in have.items()) or 'none'
            raise BagContentError(
                f'bag {self.path} has no messages on {", ".join(missing)}, needed {why}; topics in '
                f'the bag (messages): {present}. Record those topics (`wind-shaper record` records '
                f'them all by default)')

    def messages(self, topics: Iterable[str] | None = None,
                 start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[tuple[str, int, bytes]]:
        """(topic, receive time [ns], raw CDR bytes) in time order, for ``topics`` (None: all)
        and receive times in [start_ns, stop_ns)."""
        reader = self._open_reader()
        wanted = None if topics is None else set(topics)
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        try:
            for conn, t_ns, raw in reader.messages(connections=conns, start=start_ns, stop=stop_ns):
                yield conn.topic, int(t_ns), raw
        except Exception as exc:  # a chunk cut short or overwritten
            raise self._damaged(exc) from None

    def decoded(self, topics: Iterable[str] | None = None, **window) -> Iterator[tuple[str, int, object]]:
        """(topic, receive time [ns], rosbags message object), like ``messages()``."""
        store = typestore()
        msgtypes = {name: info.msgtype for name, info in self.topics.items()}
        for topic, t_ns, raw in self.messages(topics, **window):
            try:
                msg = store.deserialize_cdr(raw, msgtypes[topic])
            except KeyError:
                raise BagContentError(f'bag {self.path}: topic {topic} has type {msgtypes[topic]!r}, '
                                      f'unknown to the typestore; read it with its own package') from None
            except Exception as exc:
                raise BagReadError(f'bag {self.path}: a {msgtypes[topic]} message on {topic} at '
                                   f'{t_ns} ns cannot be decoded ({type(exc).__name__}: {exc}): the '
                                   f'bag is damaged or was written with another definition of '
                                   f'the type') from None
            yield topic, t_ns, msg


def bag_summary(path: Path | str) -> str:
    """A few lines describing a bag: duration, messages and topics."""
    with BagReader(path) as bag:
        lines = [f'bag {bag.path}: {bag.message_count} messages over {bag.duration_s:.2f} s']
        for info in bag.topics.values():
            lines.append(f'  {info.name}  [{info.msgtype}]  {info.count}')
    return '\n'.join(lines)
