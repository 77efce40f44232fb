"""Touch recordings as rosbag2 (sqlite3 or mcap), standard message types only.

Topics (all stamps = the skin data time; metres, radians, REP-103 frames):

* ``/joint_states`` - sensor_msgs/msg/JointState, NAOqi joint names.
* ``/skin/<part>/taxels`` - sensor_msgs/msg/PointCloud2, one point per activated
  taxel: ``x y z`` float32 (taxel position in the part's local frame, i.e. its
  chain end frame as the taxel file gives it; ``header.frame_id`` = that frame),
  ``slot`` uint32, ``pressure`` float32 (NaN unknown), ``contact`` int32
  (skinManager contactId, -1 none). An empty cloud means "nothing pressed".
* ``/skin/<part>/contacts`` - sensor_msgs/msg/PointCloud2, one point per
  skinManager contact: ``x y z`` COP, ``nx ny nz`` normal, ``gx gy gz``
  geometric centre, ``fx fy fz`` force, ``mx my mz`` moment, ``pressure``
  average pressure (float32, NaN unknown), ``contact`` int32 id. Same stamp as
  the taxels message of that sample.

A *touch bag* (metadata ``custom_data: nao_skin.bag_kind: touches``) holds per
touch one JointState (angles already at the touch stamp) and the skin messages
of the touching parts, all at that stamp; a *stream* bag holds the same topics
at their own rates. Both are read by :func:`read_touches` through the same
:class:`~nao_skin.events.EventDetector` as live capture; only its tolerances
differ (:data:`~nao_skin.events.TOUCH_BAG_CONFIG` for touch bags).

Bags are written as rosbag2 metadata version 8 (what ROS 2 Jazzy writes and
reads) with the Jazzy type store.
"""
from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np

from nao_skin.errors import DataError
from nao_skin.model.skin import SkinModel
from nao_skin.touch.contacts import DEFAULT_MAX_NEIGHBOR_DIST, cluster_contacts, contact_geometry
from nao_skin.touch.datasets import LoadReport
from nao_skin.touch.events import LIVE_CONFIG, TOUCH_BAG_CONFIG, EventConfig, EventDetector, touchset_from_records
from nao_skin.touch.touches import TouchSet

JOINT_TOPIC = "/joint_states"
BAG_KIND_KEY = "nao_skin.bag_kind"
BAG_VERSION = 8              # rosbag2 metadata version of ROS 2 Jazzy
JOINT_STATE = "sensor_msgs/msg/JointState"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"

TAXEL_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("slot", "<u4"),
                        ("pressure", "<f4"), ("contact", "<i4")])
CONTACT_DTYPE = np.dtype([(n, "<f4") for n in ("x", "y", "z", "nx", "ny", "nz", "gx", "gy", "gz",
                                                 "fx", "fy", "fz", "mx", "my", "mz", "pressure")]
                         + [("contact", "<i4")])
# sensor_msgs/PointField datatype codes
_POINT_FIELD_CODE = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
_CODE_DTYPE = {v: k for k, v in _POINT_FIELD_CODE.items()}
_SKIN_TOPIC = re.compile(r"^/skin/([^/]+)/(taxels|contacts)$")


def taxels_topic(part: str) -> str:
    return f"/skin/{part}/taxels"


def contacts_topic(part: str) -> str:
    return f"/skin/{part}/contacts"


# ---------------------------------------------------------------------- PointCloud2 <-> numpy
def point_fields(dtype: np.dtype) -> list:
    """``(name, offset, datatype, count)`` of each PointField for a structured dtype."""
    return [(name, int(dtype.fields[name][1]), _POINT_FIELD_CODE[dtype.fields[name][0].str[1:]], 1)
            for name in dtype.names]


def decode_cloud(fields, data, point_step: int, n_points: int, is_bigendian: bool = False,
                 where: str = "point cloud") -> np.ndarray:
    """PointCloud2 payload to a structured array, whatever the field order or padding.

    ``fields``: objects with ``name``, ``offset``, ``datatype``, ``count``
    (rosbags or rclpy PointField). Raises :class:`DataError` naming ``where``.
    """
    byte_order = ">" if is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in fields:
        code = _CODE_DTYPE.get(int(f.datatype))
        if code is None or int(f.count) != 1:
            raise DataError(f"{where}: field '{f.name}' has unsupported datatype {f.datatype} / count {f.count}")
        names.append(f.name)
        formats.append(byte_order + code)
        offsets.append(int(f.offset))
    try:
        dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(point_step)})
        buf = np.frombuffer(bytes(data), dtype=np.uint8)
        if len(buf) < n_points * point_step:
            raise ValueError(f"{len(buf)} bytes for {n_points} points of {point_step}")
        return np.frombuffer(buf[: n_points * point_step].tobytes(), dtype=dtype, count=n_points)
    except (ValueError, TypeError) as exc:
        raise DataError(f"{where}: malformed point cloud ({exc})") from None


def _field(cloud: np.ndarray, name: str, default, dtype, where: str):
    if name in cloud.dtype.names:
        return cloud[name].astype(dtype)
    if default is None:
        raise DataError(f"{where}: point cloud has no field '{name}'")
    return np.full(len(cloud), default, dtype=dtype)


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


# ---------------------------------------------------------------------- writing
class BagWriter:
    """Write the nao_skin topics to a new rosbag2 (context manager). Used for touch and stream bags.

    ``live``: a recording that grows while others may read it (pairing_recorder).
    While open, the bag directory holds :data:`LOCK_FILE` naming the writing
    process, so a reader can tell a recording in progress from one whose
    recorder died; it is removed once the bag is closed (metadata complete).
    """

    def __init__(self, path: str | Path, storage: str = "sqlite3", kind: str = "stream", live: bool = False):
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
        if storage not in plugins:
            raise DataError(f"{path}: storage must be one of {', '.join(plugins)}, not {storage!r}")
        self.path = Path(path)
        if self.path.exists():
            raise DataError(f"{self.path}: exists already; a bag is never overwritten")
        self.store = _typestore()
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=plugins[storage])
        self._writer.set_custom_data(BAG_KIND_KEY, kind)
        self._kind = kind
        self._live = live
        self._connections: dict = {}
        t = self.store.types
        self._Header, self._Time = t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"]
        self._JointState, self._Cloud, self._Field = t[JOINT_STATE], t[POINT_CLOUD], t["sensor_msgs/msg/PointField"]
        self._fields = {dt: [self._Field(name=n, offset=o, datatype=c, count=k) for n, o, c, k in point_fields(dt)]
                        for dt in (TAXEL_DTYPE, CONTACT_DTYPE)}

    def __enter__(self) -> "BagWriter":
        self._writer.open()
        if self._live:          # first: no reader may take the bag for an abandoned one
            _write_lock(self.path)
        self._write_provisional_metadata()
        return self

    # Live recording (pairing_recorder): survive ``kill -9``. rosbags writes
    # metadata.yaml and the mcap summary only on close, so a provisional
    # metadata.yaml (bag kind, file name, no counts) is written at open, and
    # flush() puts every message written so far on disk as complete mcap
    # records (sqlite3: a commit). A killed recorder leaves a cut mcap file (or
    # a sqlite3 file without listed messages) that read_touches reads up to the
    # last flush, with the right bag kind.
    def _write_provisional_metadata(self) -> None:
        import yaml

        storage = self._writer.storage
        info = {"version": BAG_VERSION, "storage_identifier": self._writer.storage_plugin.name.lower(),
                "relative_file_paths": [storage.path.name], "duration": {"nanoseconds": 0},
                "starting_time": {"nanoseconds_since_epoch": 0}, "message_count": 0,
                "topics_with_message_count": [], "compression_format": "", "compression_mode": "",
                "files": [], "custom_data": {BAG_KIND_KEY: self._kind}, "ros_distro": "rosbags"}
        (self.path / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))

    def flush(self) -> None:
        """Make everything written so far durable (a later ``kill -9`` loses nothing before this)."""
        import os

        storage = self._writer.storage
        if hasattr(storage, "close_chunk"):              # mcap: end the open chunk, write it out
            if storage.chunk.bio.tell():
                storage.close_chunk()
            storage.bio.flush()
            os.fsync(storage.bio.fileno())
        elif hasattr(storage, "conn"):                   # sqlite3
            storage.conn.commit()

    def __exit__(self, *exc) -> None:
        self._writer.close()
        if self._live:          # only now: a reader seeing no lock finds complete metadata
            (self.path / LOCK_FILE).unlink(missing_ok=True)

    def _header(self, stamp_ns: int, frame: str):
        return self._Header(stamp=self._Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000)),
                            frame_id=frame)

    def _write(self, topic: str, msgtype: str, msg, stamp_ns: int) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.store)
            self._connections[topic] = conn
        self._writer.write(conn, stamp_ns, self.store.serialize_cdr(msg, msgtype))

    def write_joint_state(self, stamp_ns: int, names, positions) -> None:
        msg = self._JointState(header=self._header(stamp_ns, ""), name=list(names),
                               position=np.asarray(positions, dtype=np.float64),
                               velocity=np.zeros(0), effort=np.zeros(0))
        self._write(JOINT_TOPIC, JOINT_STATE, msg, stamp_ns)

    def _cloud(self, stamp_ns: int, frame: str, points: np.ndarray):
        return self._Cloud(header=self._header(stamp_ns, frame), height=1, width=len(points),
                           fields=self._fields[points.dtype], is_bigendian=False,
                           point_step=points.dtype.itemsize, row_step=points.dtype.itemsize * len(points),
                           data=np.frombuffer(points.tobytes(), dtype=np.uint8), is_dense=True)

    def write_taxels(self, stamp_ns: int, part: str, frame: str, positions, slots, pressures, contact_ids) -> None:
        pts = np.zeros(len(slots), dtype=TAXEL_DTYPE)
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        pts["x"], pts["y"], pts["z"] = positions.T
        pts["slot"], pts["pressure"], pts["contact"] = slots, pressures, contact_ids
        self._write(taxels_topic(part), POINT_CLOUD, self._cloud(stamp_ns, frame, pts), stamp_ns)

    def write_contacts(self, stamp_ns: int, part: str, frame: str, contact_ids, cop, normal=None,
                       geo_center=None, force=None, moment=None, pressure=None) -> None:
        n = len(contact_ids)
        pts = np.zeros(n, dtype=CONTACT_DTYPE)
        for names, value in ((("x", "y", "z"), cop), (("nx", "ny", "nz"), normal), (("gx", "gy", "gz"), geo_center),
                             (("fx", "fy", "fz"), force), (("mx", "my", "mz"), moment)):
            value = np.full((n, 3), np.nan) if value is None else np.asarray(value, dtype=float).reshape(n, 3)
            for k, name in enumerate(names):
                pts[name] = value[:, k]
        pts["pressure"] = np.nan if pressure is None else pressure
        pts["contact"] = contact_ids
        self._write(contacts_topic(part), POINT_CLOUD, self._cloud(stamp_ns, frame, pts), stamp_ns)


def _stamp_ns(stamp: float, where: str) -> int:
    if not np.isfinite(stamp) or stamp < 0:
        raise DataError(f"{where}: stamp {stamp!r} is not a non-negative time")
    return int(round(float(stamp) * 1e9))


def write_touch_bag(path: str | Path, touches: TouchSet, skin: SkinModel, storage: str = "sqlite3") -> None:
    """Write a touch bag: per touch (in stamp order) one JointState and the touching parts' skin messages.

    Taxel positions are those of the nominal layout (what a skin driver sends);
    a contacts message lists the recorded skinManager contacts (id >= 0) with
    their recorded COP, the layout's geometric centre and normal, and the mean
    activation pressure; force and moment are not kept in a TouchSet (NaN).
    """
    path = Path(path)
    geom = contact_geometry(touches, skin, None)
    act_touch, act_part = touches.act_touch, touches.act_part
    act_cid = touches.contact_id[touches.act_contact]
    c_pressure = np.bincount(touches.act_contact, weights=np.nan_to_num(touches.act_pressure, nan=0.0),
                             minlength=len(touches.contact_touch)) / np.maximum(geom.n_taxels, 1)
    c_has_pressure = np.bincount(touches.act_contact, weights=np.isfinite(touches.act_pressure),
                                 minlength=len(touches.contact_touch)) == geom.n_taxels
    c_pressure = np.where(c_has_pressure, c_pressure, np.nan)
    # touches in stamp order; activations and contacts grouped per touch for slicing
    order = np.argsort(touches.stamps, kind="stable")
    a_order = np.lexsort((act_part, act_touch))
    a_bounds = np.searchsorted(act_touch[a_order], np.arange(touches.n_touches + 1))
    c_order = np.lexsort((touches.contact_part, touches.contact_touch))
    c_bounds = np.searchsorted(touches.contact_touch[c_order], np.arange(touches.n_touches + 1))
    with BagWriter(path, storage, kind="touches") as bag:
        for t in order:                               # one message group per touch: I/O, not maths
            stamp_ns = _stamp_ns(touches.stamps[t], f"{path}: touch {touches.keys[t]!r}")
            bag.write_joint_state(stamp_ns, touches.joint_names, touches.joints[t])
            acts = a_order[a_bounds[t]:a_bounds[t + 1]]
            cons = c_order[c_bounds[t]:c_bounds[t + 1]]
            for p in np.unique(act_part[acts]):
                name = touches.part_names[p]
                part = skin.part(name)
                a = acts[act_part[acts] == p]
                slots = touches.act_slot[a]
                bag.write_taxels(stamp_ns, name, part.parent_frame, part.positions[slots], slots,
                                 touches.act_pressure[a], act_cid[a])
                c = cons[(touches.contact_part[cons] == p) & (touches.contact_id[cons] >= 0)]
                bag.write_contacts(stamp_ns, name, part.parent_frame, touches.contact_id[c], touches.contact_cop[c],
                                   geom.normal[c], geom.geo_center[c], pressure=c_pressure[c])


# ---------------------------------------------------------------------- reading
def _bag_kind(reader) -> str:
    custom = getattr(getattr(reader, "storage", None), "metadata", None)
    custom = getattr(custom, "custom", None) or {}
    return str(custom.get(BAG_KIND_KEY, "stream"))


def read_touches(path: str | Path, skin: SkinModel, config: EventConfig | None = None,
                 max_neighbor_dist: float = DEFAULT_MAX_NEIGHBOR_DIST, cluster: bool = True) -> tuple:
    """Touches of a touch bag or a stream bag: ``(TouchSet, LoadReport)``.

    ``config`` defaults to the bag's kind (touch bag: exact stamps; stream:
    live tolerances). Taxels without a skinManager contact are clustered
    with ``max_neighbor_dist`` unless ``cluster`` is False. A bag that breaks
    off (truncated file) keeps what was read before, and says so. A bag that
    was never closed (recording in progress, or its recorder died) is read
    from its storage file as far as it was written, and the report says which
    of the two it is.
    """
    from rosbags.rosbag2 import Reader

    path = Path(path)
    report = LoadReport(str(path))
    # metadata.yaml lists the messages only once the bag is closed: read an unclosed sqlite3 file itself
    unclosed = _unclosed_sqlite(path)
    if unclosed is not None:
        return _read_unclosed_sqlite(path, *unclosed, skin, config, max_neighbor_dist, cluster, report)
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags, sqlite and yaml all raise their own types
        damaged = sorted(path.glob("*.mcap")) if path.is_dir() else []
        if len(damaged) != 1:
            raise DataError(f"{path}: cannot open as a rosbag2 ({_one_line(exc)})") from None
        return _read_salvaged(path, damaged[0], skin, config, max_neighbor_dist, cluster, report, exc)
    try:
        kind = _bag_kind(reader)
        detector = EventDetector.for_skin(skin, config or (TOUCH_BAG_CONFIG if kind == "touches" else LIVE_CONFIG))
        store = _typestore()
        wanted, unknown = [], {}
        for conn in reader.connections:
            m = _SKIN_TOPIC.match(conn.topic)
            if conn.topic == JOINT_TOPIC and conn.msgtype == JOINT_STATE:
                wanted.append(conn)
            elif m and conn.msgtype == POINT_CLOUD:
                if m.group(1) in skin.parts:
                    wanted.append(conn)
                else:
                    unknown[conn.topic] = conn.msgcount
        for topic, count in unknown.items():
            report.skip("unknown skin part", f"{path}: topic '{topic}': skin part '{_SKIN_TOPIC.match(topic).group(1)}'"
                                             f" is not configured ({', '.join(skin.parts)}); {count} messages skipped",
                        count=count)
        records, n_msgs = [], 0
        try:
            for conn, _, raw in reader.messages(connections=wanted):
                n_msgs += 1
                try:
                    records += _feed(detector, store, conn, raw, skin, path)
                except DataError as exc:
                    report.skip(getattr(exc, "reason", "bad message"), str(exc), part=getattr(exc, "part", None))
        except Exception as exc:  # noqa: BLE001 - a broken file raises whatever its storage library raises
            report.skip("truncated bag", f"{path}: unreadable after {n_msgs} messages ({_one_line(exc)});"
                                         f" the rest of the bag is lost")
        records += detector.flush()
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001 - closing a broken bag must not hide what was read
            pass
    return _finish(detector, records, n_msgs, skin, max_neighbor_dist, cluster, report)


def _finish(detector, records, n_msgs, skin, max_neighbor_dist, cluster, report) -> tuple:
    for reason, count in detector.counts.items():
        if reason not in ("touches", "continued press"):
            report.skipped[reason] += count
    report.messages.extend(f"{report.source}: {note}" for note in detector.notes)
    touches = touchset_from_records(records, detector.part_names, detector.joint_names)
    if cluster:
        touches = cluster_contacts(touches, skin, None, max_neighbor_dist)
    report.n_read = n_msgs
    report.n_loaded = touches.n_touches
    report.unit = "messages"
    return touches, report


# ---------------------------------------------------------------------- damaged mcap files
class _Conn:
    """What :func:`_feed` needs of a connection."""

    def __init__(self, topic: str, msgtype: str):
        self.topic, self.msgtype = topic, msgtype


def _mcap_messages(buf: bytes):
    """``(topic, msgtype, data)`` of an mcap file read front to back, stopping where it breaks off.

    A cut file lacks the footer and summary the normal reader needs, but its
    records are length-prefixed: every complete one before the cut is intact.
    Yields ``(None, error, None)`` once if the file ends inside a record.
    """
    u16 = lambda b, o: int.from_bytes(b[o:o + 2], "little")          # noqa: E731
    u32 = lambda b, o: int.from_bytes(b[o:o + 4], "little")          # noqa: E731
    u64 = lambda b, o: int.from_bytes(b[o:o + 8], "little")          # noqa: E731

    def string(b, o):
        n = u32(b, o)
        return b[o + 4:o + 4 + n].decode(), o + 4 + n

    schemas, channels = {}, {}

    def walk(b, pos, end, top):
        while pos < end:
            if pos + 9 > end:
                yield None, "ends inside a record header", None
                return
            op, length = b[pos], u64(b, pos + 1)
            start, stop = pos + 9, pos + 9 + length
            if stop > end:
                if op == 0x06 and top:        # a cut chunk: its complete inner records are still good
                    inner = start + 8 + 8 + 8 + 4
                    comp, inner = string(b, inner)
                    if comp == "":
                        yield from walk(b, inner + 8, end, False)
                yield None, f"ends inside a record at byte {pos} of {end}", None
                return
            if op == 0x03:
                sid = u16(b, start)
                name, _ = string(b, start + 2)
                schemas[sid] = name
            elif op == 0x04:
                cid, sid = u16(b, start), u16(b, start + 2)
                topic, _ = string(b, start + 4)
                channels[cid] = _Conn(topic, schemas.get(sid, ""))
            elif op == 0x05:
                conn = channels.get(u16(b, start))
                if conn is not None:
                    yield conn.topic, conn.msgtype, b[start + 22:stop]
            elif op == 0x06:
                inner = start + 8 + 8 + 8 + 4
                comp, inner = string(b, inner)
                if comp != "":
                    yield None, f"compressed chunk ({comp}) cannot be salvaged", None
                    return
                yield from walk(b, inner + 8, stop, False)
            pos = stop

    if not buf.startswith(b"\x89MCAP0\r\n"):
        yield None, "not an mcap file", None
        return
    yield from walk(buf, 8, len(buf), True)


def _read_salvaged(path, file, skin, config, max_neighbor_dist, cluster, report, open_error) -> tuple:
    """A bag whose mcap file is cut off (recording in progress, recorder died, damage): read up to the cut."""
    writer = _recording_lock(path)        # before reading: a recorder closing meanwhile is still "open" here
    try:
        buf = file.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read {file.name} ({exc.strerror})") from None
    detector, records, n_msgs, why = _read_messages(path, _mcap_messages(buf), skin, config, report)
    if writer is None:
        report.skip("truncated bag", f"{path}: {file.name} is damaged ({_one_line(open_error)}); read {n_msgs}"
                                     f" messages up to where it {why}, the rest is lost")
    elif writer.state == "died":
        report.skip("truncated bag", f"{path}: {writer.who} died before closing the bag; read {n_msgs} messages"
                                     f" of {file.name} (the file {why}); anything after its last flush is lost")
    touches, report = _finish(detector, records, n_msgs, skin, max_neighbor_dist, cluster, report)
    if writer is not None and writer.state != "died":
        report.notes.append(writer.still_open(path, file, n_msgs, touches.n_touches))
    return touches, report


def _read_messages(path, messages, skin, config, report) -> tuple:
    """Feed ``(topic, msgtype, data)`` of a bag read without rosbags to a detector.

    ``(None, why, None)`` ends the messages where the file breaks off. Returns
    ``(detector, records, messages fed, how the messages end)``.
    """
    detector = EventDetector.for_skin(skin, config or _salvage_config(path))
    store = _typestore()
    records, n_msgs, why = [], 0, "ends cleanly"
    unknown = Counter()
    for topic, msgtype, data in messages:
        if topic is None:
            why = msgtype
            break
        m = _SKIN_TOPIC.match(topic)
        if not ((topic == JOINT_TOPIC and msgtype == JOINT_STATE) or (m and msgtype == POINT_CLOUD)):
            continue
        if m and m.group(1) not in skin.parts:
            unknown[topic] += 1
            continue
        n_msgs += 1
        try:
            records += _feed(detector, store, _Conn(topic, msgtype), data, skin, path)
        except DataError as exc:
            report.skip(getattr(exc, "reason", "bad message"), str(exc), part=getattr(exc, "part", None))
    for topic, count in unknown.items():
        report.skip("unknown skin part", f"{path}: topic '{topic}': skin part '{_SKIN_TOPIC.match(topic).group(1)}'"
                                         f" is not configured ({', '.join(skin.parts)}); {count} messages skipped",
                    count=count)
    records += detector.flush()
    return detector, records, n_msgs, why


# ---------------------------------------------------------------------- recordings never closed
LOCK_FILE = "recording.lock"          # in a live bag's directory while its writer has it open


class _Lock:
    """A bag's :data:`LOCK_FILE`: who writes it, and whether that process still runs."""

    def __init__(self, pid, host, state: str):
        self.pid, self.host, self.state = pid, host, state      # state: open, died or unknown

    @property
    def who(self) -> str:
        return f"the recorder (pid {self.pid} on {self.host})"

    def still_open(self, path, file, n_msgs: int, n_touches: int) -> str:
        """The report line of a recording read while (maybe) still being written."""
        read = f"read {n_msgs} messages of {file.name} written so far: {n_touches} touches"
        if self.state == "open":
            return f"{path}: the recording is still open (being recorded by pid {self.pid} on {self.host}); {read}"
        if self.pid is None:
            return f"{path}: {LOCK_FILE} is unreadable: the recording may still be open or its recorder died; {read}"
        return (f"{path}: {LOCK_FILE} names pid {self.pid} on host {self.host}, which cannot be checked from here:"
                f" the recording is open if that recorder still runs, else it died; {read}")


def _write_lock(path: Path) -> None:
    import json
    import os
    import socket

    info = {"pid": os.getpid(), "host": socket.gethostname(), "start": _process_start(os.getpid())}
    (path / LOCK_FILE).write_text(json.dumps(info) + "\n")


def _process_start(pid: int) -> str | None:
    """A running process's start time (Linux); None when it is gone or a zombie, or there is no /proc."""
    try:
        fields = Path(f"/proc/{int(pid)}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError, ValueError):
        return None
    return None if fields[0] in ("Z", "X") else fields[19]


def _recording_lock(path: Path) -> _Lock | None:
    """The bag's lock, if its writer left one: it holds the bag open now (state open) or died without closing it."""
    import json
    import os
    import socket

    lock = path / LOCK_FILE if path.is_dir() else None
    if lock is None or not lock.exists():
        return None
    try:
        info = json.loads(lock.read_text())
        pid, host, start = int(info["pid"]), str(info["host"]), info.get("start")
    except (OSError, ValueError, KeyError, TypeError):
        return _Lock(None, None, "unknown")
    if host != socket.gethostname():
        return _Lock(pid, host, "unknown")
    if Path("/proc/self/stat").exists():
        # the start time tells the recorder from a later process that got its pid
        now = _process_start(pid)
        return _Lock(pid, host, "open" if now is not None and start in (None, now) else "died")
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return _Lock(pid, host, "died")
    except PermissionError:
        pass
    return _Lock(pid, host, "open")


def _unclosed_sqlite(path: Path) -> tuple | None:
    """``(db3 file, reason, why)`` of a sqlite3 bag whose metadata.yaml does not list its messages."""
    import yaml

    files = sorted(path.glob("*.db3")) if path.is_dir() else []
    if len(files) != 1:
        return None
    meta = path / "metadata.yaml"
    if not meta.exists():
        return files[0], "no metadata", "it has no metadata.yaml"
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        listed = bool(info.get("files") or info.get("topics_with_message_count"))
    except Exception as exc:  # noqa: BLE001 - yaml and a malformed layout raise assorted types
        return files[0], "no metadata", f"its metadata.yaml is unreadable ({_one_line(exc)})"
    # BagWriter's provisional metadata (written at open) lists neither; the real one, written on close, both
    return None if listed else (files[0], "truncated bag", "metadata.yaml is incomplete (the recorder did not close"
                                                           " the bag; anything after its last commit is lost)")


def _sqlite_messages(path: Path, file: Path) -> list:
    """``(topic, msgtype, data)`` of every message committed to a rosbag2 sqlite3 file, in time order.

    Read-only, in one query: a live recorder's next commit waits at most that long.
    """
    import sqlite3
    from contextlib import closing

    query = ("SELECT t.name, t.type, m.data FROM messages AS m JOIN topics AS t ON m.topic_id = t.id"
             " ORDER BY m.timestamp, m.id")
    try:
        with closing(sqlite3.connect(f"{file.resolve().as_uri()}?mode=ro", uri=True, timeout=1.0)) as conn:
            return conn.execute(query).fetchall()
    except sqlite3.Error as exc:
        name = getattr(exc, "sqlite_errorname", "")
        if not (name in ("SQLITE_READONLY_ROLLBACK", "SQLITE_BUSY") or "readonly" in str(exc)
                or "locked" in str(exc)):
            raise DataError(f"{path}: cannot read {file.name} ({_one_line(exc)})") from None
    # the writer's open transaction has reached the file (it holds the file locked, or died so): sqlite
    # must roll its journal back, which a read-only reader cannot; do it on a copy, leave the recording be
    return _sqlite_messages_of_copy(path, file, query)


def _sqlite_messages_of_copy(path: Path, file: Path, query: str, attempts: int = 5) -> list:
    import shutil
    import sqlite3
    import tempfile
    from contextlib import closing

    journal = file.with_name(file.name + "-journal")

    def state():
        return tuple((f.stat().st_size, f.stat().st_mtime_ns) if f.exists() else None for f in (file, journal))

    with tempfile.TemporaryDirectory(prefix="nao_skin_db3_") as tmp:
        copy = Path(tmp) / file.name
        for _ in range(attempts):
            before = state()
            try:
                shutil.copyfile(file, copy)
                if before[1] is not None:
                    shutil.copyfile(journal, copy.with_name(journal.name))
            except FileNotFoundError:       # the writer committed meanwhile (journal gone): again
                pass
            else:
                if state() == before:       # a live writer changed neither file while they were copied
                    break
            for f in Path(tmp).iterdir():
                f.unlink()
        else:
            raise DataError(f"{path}: {file.name} kept changing while it was read; read it again")
        try:
            with closing(sqlite3.connect(copy)) as conn:
                return conn.execute(query).fetchall()
        except sqlite3.Error as exc:
            raise DataError(f"{path}: cannot read {file.name} ({_one_line(exc)})") from None


def _read_unclosed_sqlite(path, file, reason, why, skin, config, max_neighbor_dist, cluster, report) -> tuple:
    """A sqlite3 bag never closed: every committed message, from the file itself; say whether it is still open."""
    writer = _recording_lock(path)        # before reading: a recorder closing meanwhile is still "open" here
    detector, records, n_msgs, _ = _read_messages(path, _sqlite_messages(path, file), skin, config, report)
    if writer is None:
        report.skip(reason, f"{path}: {why}; read {n_msgs} messages from {file.name} directly")
    elif writer.state == "died":
        report.skip("truncated bag", f"{path}: {writer.who} died before closing the bag; read {n_msgs} messages"
                                     f" from {file.name} directly, up to its last flush; anything after that is lost")
    touches, report = _finish(detector, records, n_msgs, skin, max_neighbor_dist, cluster, report)
    if writer is not None and writer.state != "died":
        report.notes.append(writer.still_open(path, file, n_msgs, touches.n_touches))
    return touches, report


def _salvage_config(path: Path) -> EventConfig:
    """Detector settings for a cut bag: its provisional metadata.yaml names the kind; default a stream."""
    import yaml

    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        kind = str((info.get("custom_data") or {}).get(BAG_KIND_KEY, "stream"))
    except Exception:  # noqa: BLE001 - no or unreadable metadata: nothing says it is a touch bag
        kind = "stream"
    return TOUCH_BAG_CONFIG if kind == "touches" else LIVE_CONFIG


class _BadMessage(DataError):
    """One unusable message; ``reason`` is the short key it is counted under."""

    def __init__(self, reason: str, message: str, part: str | None = None):
        super().__init__(message)
        self.reason = reason
        self.part = part        # set when the part's layout lacks a named slot


def _one_line(exc: Exception) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:300]


def _feed(detector: EventDetector, store, conn, raw, skin: SkinModel, path: Path) -> list:
    """Decode one message and hand it to the detector; DataError names bag, topic and stamp."""
    try:
        msg = store.deserialize_cdr(raw, conn.msgtype)
    except Exception as exc:  # noqa: BLE001 - CDR decoding raises assorted errors on bad bytes
        raise DataError(f"{path}: topic '{conn.topic}': undecodable {conn.msgtype} ({_one_line(exc)})") from None
    stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    where = f"{path}: topic '{conn.topic}' at {stamp:.9f}"
    if conn.topic == JOINT_TOPIC:
        return detector.add_joint_state(stamp, msg.name, msg.position)
    part_name, what = _SKIN_TOPIC.match(conn.topic).groups()
    cloud = decode_cloud(msg.fields, msg.data, msg.point_step, msg.width * msg.height, msg.is_bigendian, where)
    if what == "contacts":
        cop = np.stack([_field(cloud, k, None, float, where) for k in ("x", "y", "z")], axis=1)
        return detector.add_contacts(stamp, part_name, _field(cloud, "contact", None, int, where), cop)
    slots = _field(cloud, "slot", None, np.int64, where)
    part = skin.parts[part_name]
    bad = (slots < 0) | (slots >= part.n_slots)
    if np.any(bad):
        raise _BadMessage("bad taxel slot", f"{where}: field 'slot': slot {int(slots[bad][0])} out of range 0..{part.n_slots - 1}"
                        f" of part '{part_name}'; sample skipped", part_name)
    absent = ~part.present[slots]
    if np.any(absent):
        raise _BadMessage("bad taxel slot", f"{where}: field 'slot': slot {int(slots[absent][0])} is not a taxel of the"
                        f" '{part_name}' layout ({part.layout_file}); sample skipped", part_name)
    return detector.add_skin(stamp, part_name, slots.tolist(), _field(cloud, "pressure", np.nan, float, where).tolist(),
                             _field(cloud, "contact", -1, int, where).tolist())
