"""Touch recordings as rosbag2 (sqlite3 or mcap), standard message types only.

Topics and their message layouts: :mod:`nao_skin.formats.pointcloud`
(``/joint_states``, ``/skin/<part>/taxels``, ``/skin/<part>/contacts``); all
stamps are the skin data time.

A *touch bag* (metadata ``custom_data: nao_skin.bag_kind: touches``) holds per
touch one JointState (angles already at the touch stamp) and the skin messages
of the touching parts, all at that stamp; a *stream* bag holds the same topics
at their own rates. Both are read by :func:`read_touches` through the same
:class:`~nao_skin.touch.events.EventDetector` as live capture; only its tolerances
differ (:data:`~nao_skin.touch.events.TOUCH_BAG_CONFIG` for touch bags), and a stream
bag's topics are read in the order of their stamps, as the live recorder reads them
(:class:`~nao_skin.touch.inorder.InOrder`). A bag
rosbags cannot open (never closed, or cut off) is read from its storage file
(:mod:`nao_skin.formats.salvage`).

Bags are written as rosbag2 metadata version 9 (what ROS 2 Jazzy's rosbag2 writes: QoS profiles as a
YAML list, ``ros_distro``, ``custom_data``, each topic's ``type_description_hash``) with the Jazzy type
store. A bag directory nao-skin names has no ``.bag`` suffix: rosbags' ``AnyReader`` (and ROS 1 tools) take a
``*.bag`` path for a ROS 1 bag file. Reading goes through rosbags' rosbag2 ``Reader``, which takes any
directory name, so a user's ``something.bag`` rosbag2 directory is read as any other.
"""
from __future__ import annotations

import copy
import errno
import json
import os
import shutil
import sqlite3
from collections import Counter
from pathlib import Path

import numpy as np

from nao_skin.errors import BagMoved, DataError, DiskFull, NaoSkinError, OutputError, one_line, os_reason
from nao_skin.formats.outdir import staging_dir
from nao_skin.formats.pointcloud import (FINGERTIP_TOUCH_TOPIC, JOINT_STATES_TOPIC, LAST_STAMP, contacts_array,
                                         contacts_topic, encode_cloud,
                                         header_seconds, read_contacts, read_taxels, skin_topic, taxels_array,
                                         taxels_topic)
from nao_skin.formats.salvage import (LOCK_FILE, RESCUED_FROM_KEY, bag_metadata, check_storage_files, cut_mcap,
                                      cut_sqlite, provisional_mcap, stored_metadata, unclosed_sqlite, write_lock)
from nao_skin.model.skin import SkinModel
from nao_skin.paths import free_sibling, identity
from nao_skin.touch.contacts import DEFAULT_MAX_NEIGHBOR_DIST, cluster_contacts, contact_geometry
from nao_skin.touch.datasets import LoadReport
from nao_skin.touch.events import (LIVE_CONFIG, TOUCH_BAG_CONFIG, EventConfig, EventDetector,
                                   touchset_from_records)
from nao_skin.touch.inorder import InOrder
from nao_skin.touch.touches import TouchSet

BAG_KIND_KEY = "nao_skin.bag_kind"
CLOCK_STEP_S = 1.0     # s a stream bag's clock moves at most per message read (_Feed)
SOURCE_KEY = "nao_skin.recorded_from"     # what a recorder was fed: a simulated robot is said on every read (info)
SIMULATED = "the simulated robot (sim_robot)"
CONTINUES_KEY = "nao_skin.continues"        # the earlier sittings' bags a record session continued: a JSON list
CONTINUES_RELATIVE_KEY = "nao_skin.continues_relative"     # ... relative to the bag's folder (moved together)
SIM_SEED_KEY = "nao_skin.sim_seed"          # the seed the simulated robot played: a session continuing the bag
                                             # plays another (the same seed plays the same touches again)
BAG_VERSION = 9              # rosbag2 metadata version ROS 2 Jazzy's rosbag2 writes (rosbags writes 8 or 9)
JOINT_STATE = "sensor_msgs/msg/JointState"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


# ---------------------------------------------------------------------- writing
# what a write to a bag raises when the disk is full or a file size limit is reached
WRITE_ERRORS = (OSError, sqlite3.Error)


def enclosing_bag(path: str | Path) -> Path | None:
    """The bag directory ``path`` would lie in (a parent holding a bag's metadata or recording lock), or None."""
    return next((parent for parent in Path(path).absolute().parents
                 if (parent / "metadata.yaml").is_file() or (parent / LOCK_FILE).is_file()), None)


def check_outside_bags(path: Path, label: str | Path | None = None) -> None:
    """No bag encloses ``path`` (``label``: its name in the message)."""
    outer = enclosing_bag(path)
    if outer is not None:
        raise DataError(f"{path if label is None else label}: lies inside the bag {outer}; a bag is never written"
                        f" into another, choose a place outside it")


def check_new_bag(path: Path, label: str | Path | None = None) -> None:
    """A bag can be made at ``path``: nothing is there, no bag encloses it, its folder is (made) a directory.
    ``label``: the bag's name in messages (``path`` in a staging directory the user never sees)."""
    name = path if label is None else label
    if path.exists() or path.is_symlink():
        raise DataError(f"{name}: exists already; a bag is never overwritten")
    check_outside_bags(path, name)
    for parent in path.absolute().parents:        # rosbags makes only the bag's own directory
        if parent.exists():
            if not parent.is_dir():
                raise DataError(f"{name}: {parent} is a file, not a directory; choose another place")
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{name}: cannot make its folder ({exc.strerror}); choose another place") from None


class BagWriter:
    """Write the nao_skin topics to a new rosbag2 (context manager). Used for touch and stream bags.

    ``live``: a recording that grows while others may read it (pairing_recorder).
    While open, the bag directory holds :data:`~nao_skin.formats.salvage.LOCK_FILE`
    naming the writing process, so a reader can tell a recording in progress
    from one whose recorder died; it is removed once the bag is closed
    (metadata complete).
    """

    def __init__(self, path: str | Path, storage: str = "sqlite3", kind: str = "stream", live: bool = False,
                 source: str = "", continues=(), sim_seed: int | None = None):
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

        plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
        if storage not in plugins:
            raise DataError(f"{path}: storage must be one of {', '.join(plugins)}, not {storage!r}")
        self.path = Path(path)
        check_new_bag(self.path)
        self.store = _typestore()
        try:    # checked above; another recorder may have made it since (building the type store takes ~0.25 s)
            self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=plugins[storage])
        except WriterError:
            raise DataError(f"{self.path}: exists already (made meanwhile by another recording); a bag is never"
                            f" overwritten") from None
        self._custom = {BAG_KIND_KEY: kind, **({SOURCE_KEY: source} if source else {})}
        if continues:
            folder = os.path.abspath(self.path.parent)
            self._custom[CONTINUES_KEY] = json.dumps([os.path.abspath(p) for p in continues])
            self._custom[CONTINUES_RELATIVE_KEY] = json.dumps([os.path.relpath(os.path.abspath(p), folder)
                                                               for p in continues])
        if sim_seed is not None:
            self._custom[SIM_SEED_KEY] = str(int(sim_seed))
        for key, value in self._custom.items():
            self._writer.set_custom_data(key, value)
        self._kind = kind
        self._live = live
        self._place = self._file = None     # (device, inode) of the bag's directory and storage file once open
        self._abandoned = False
        self._connections: dict = {}
        t = self.store.types
        self._Header, self._Time = t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"]
        self._JointState, self._Cloud, self._Field = t[JOINT_STATE], t[POINT_CLOUD], t["sensor_msgs/msg/PointField"]
        self._PointStamped, self._Point = t[POINT_STAMPED], t["geometry_msgs/msg/Point"]

    def __enter__(self) -> "BagWriter":
        from rosbags.rosbag2 import WriterError

        try:
            self._writer.open()
        except (FileExistsError, WriterError):
            raise DataError(f"{self.path}: exists already (made meanwhile by another recording); a bag is never"
                            f" overwritten") from None
        except OSError as exc:
            raise DataError(f"{self.path}: cannot write the bag ({exc.strerror}); choose another place") from None
        try:
            if self._live:          # first: no reader may take the bag for an abandoned one
                write_lock(self.path)
            self._write_provisional_metadata()
            self._place = identity(self.path)
            self._file = identity(self._writer.storage.path)     # the storage file's (device, inode)
        except WRITE_ERRORS as exc:
            raise self._cannot_write(exc) from None
        return self

    # Live recording (pairing_recorder): survive ``kill -9``. rosbags writes
    # metadata.yaml and the mcap summary only on close, so a provisional
    # metadata.yaml (bag kind, file name, no counts) is written at open, and
    # flush() puts every message written so far on disk as complete mcap
    # records (sqlite3: a commit). A killed recorder leaves a cut mcap file (or
    # a sqlite3 file without listed messages) that read_touches reads up to the
    # last flush, with the right bag kind.
    def _rescue_if_moved(self) -> None:
        """A live bag's directory is still the one it opened: removed (``rm -rf``), moved or replaced, the
        files it writes are no longer (or no longer only) there. Then everything written so far is copied out
        through the files still open to ``<bag>.rescued`` and :class:`BagMoved` says so; the bag is abandoned
        (closing it would write its metadata into whatever now has its name)."""
        if identity(self.path) == self._place:
            return
        self._abandoned = True
        try:
            rescued = self._rescue()
        except WRITE_ERRORS as exc:
            why = os_reason(exc) if isinstance(exc, OSError) else exc
            raise BagMoved(f"{self.path}: the bag's directory was removed, moved or replaced while recording,"
                           f" and its touches could not be copied out ({why}); recording stopped") from None
        raise BagMoved(f"{self.path}: the bag's directory was removed, moved or replaced while recording; every"
                       f" touch written so far is copied to {rescued} (nao-skin reads it: nao-skin stats {rescued});"
                       f" recording stopped")

    def _rescue(self) -> Path:
        """Copy the open storage file, as written so far, to a new ``<bag>.rescued`` directory."""
        import os

        target = Path(free_sibling(self.path, ".rescued"))
        target.mkdir(parents=True)
        storage = self._writer.storage
        if hasattr(storage, "bio"):     # mcap: what is buffered goes to the file first
            if storage.chunk.bio.tell():
                storage.close_chunk()
            storage.bio.flush()
        # the storage file's bytes through this process's open descriptor of it (opened again for reading:
        # it may have no name left). sqlite3 (rollback journal) holds its last commit in the file itself.
        open_file = next((f"/proc/self/fd/{fd}" for fd in os.listdir("/proc/self/fd")
                          if identity(f"/proc/self/fd/{fd}") == self._file), None)
        if open_file is None:
            raise OSError("its storage file is not open in this process")
        with open(open_file, "rb") as src, open(target / storage.path.name, "wb") as out:
            shutil.copyfileobj(src, out)
            out.flush()
            os.fsync(out.fileno())
        self._write_provisional_metadata(target, {RESCUED_FROM_KEY: str(self.path)})
        return target

    def _write_provisional_metadata(self, directory: Path | None = None, custom: dict | None = None) -> None:
        import yaml

        storage = self._writer.storage
        info = {"version": BAG_VERSION, "storage_identifier": self._writer.storage_plugin.name.lower(),
                "relative_file_paths": [storage.path.name], "duration": {"nanoseconds": 0},
                "starting_time": {"nanoseconds_since_epoch": 0}, "message_count": 0,
                "topics_with_message_count": [], "compression_format": "", "compression_mode": "",
                "files": [], "custom_data": {**self._custom, **(custom or {})}, "ros_distro": "rosbags"}
        ((directory or self.path) / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))

    def flush(self) -> None:
        """Make everything written so far durable (a later ``kill -9`` loses nothing before this)."""
        import os

        if self._live:      # first: a commit needs the directory (sqlite's journal)
            self._rescue_if_moved()
        storage = self._writer.storage
        try:
            if hasattr(storage, "close_chunk"):              # mcap: end the open chunk, write it out
                if storage.chunk.bio.tell():
                    storage.close_chunk()
                storage.bio.flush()
                os.fsync(storage.bio.fileno())
            elif hasattr(storage, "conn"):                   # sqlite3
                storage.conn.commit()
        except WRITE_ERRORS as exc:
            raise self._cannot_write(exc) from None

    def __exit__(self, *exc) -> None:
        if self._abandoned:         # its directory is not ours any more: leave the files as they are
            self._close_files()
            return
        if self._live and exc[0] is None:
            self.flush()            # where the touches go, checked once more before metadata is written there
        try:
            self._writer.close()
        except WRITE_ERRORS as err:
            if exc[0] is None:      # else the error being handled says more
                raise self._cannot_write(err) from None
            return
        if self._live:          # only now: a reader seeing no lock finds complete metadata
            (self.path / LOCK_FILE).unlink(missing_ok=True)

    def _close_files(self) -> None:
        """Close the storage's open files without writing anything more (an abandoned bag)."""
        storage = self._writer.storage
        for handle in (getattr(storage, "bio", None), getattr(storage, "conn", None)):
            if handle is not None:
                try:
                    handle.close()
                except WRITE_ERRORS:
                    pass

    def _cannot_write(self, exc: Exception) -> OutputError:
        """A failed write (a full disk, a file size limit) as one line; sqlite3 says 'disk I/O error'.

        A live bag whose directory went away fails so (sqlite's journal has nowhere to go): that is
        :class:`BagMoved`, raised from here with the touches copied out."""
        if self._live and self._place is not None and not self._abandoned:
            self._rescue_if_moved()
        if isinstance(exc, OSError):
            full = exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
        else:        # sqlite3 names no errno: 'database or disk is full', or 'disk I/O error' on a full disk
            free = next((shutil.disk_usage(p).free for p in (self.path, *self.path.absolute().parents)
                         if p.exists()), None)
            full = "full" in str(exc) or (free is not None and free < 1 << 20)
        return (DiskFull if full else OutputError)(
            f"{self.path}: cannot write the bag ({os_reason(exc) if isinstance(exc, OSError) else exc})")

    def _header(self, stamp_ns: int, frame: str):
        return self._Header(stamp=self._Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000)),
                            frame_id=frame)

    def _write(self, topic: str, msgtype: str, msg, stamp_ns: int) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.store)
            self._connections[topic] = conn
        try:
            self._writer.write(conn, stamp_ns, self.store.serialize_cdr(msg, msgtype))
        except WRITE_ERRORS as exc:
            raise self._cannot_write(exc) from None

    def _write_cloud(self, topic: str, stamp_ns: int, frame: str, points: np.ndarray,
                     received_ns: int | None = None) -> None:
        cloud = encode_cloud(points)
        cloud["fields"] = [self._Field(name=n, offset=o, datatype=d, count=k) for n, o, d, k in cloud["fields"]]
        cloud["data"] = np.frombuffer(cloud["data"], dtype=np.uint8)
        self._write(topic, POINT_CLOUD, self._Cloud(header=self._header(stamp_ns, frame), **cloud),
                    stamp_ns if received_ns is None else received_ns)

    def write_joint_state(self, stamp_ns: int, names, positions, received_ns: int | None = None) -> None:
        """A JointState; ``received_ns``: when a recorder got it (the bag's own time), the stamp if None."""
        msg = self._JointState(header=self._header(stamp_ns, ""), name=list(names),
                               position=np.asarray(positions, dtype=np.float64),
                               velocity=np.zeros(0), effort=np.zeros(0))
        self._write(JOINT_STATES_TOPIC, JOINT_STATE, msg, stamp_ns if received_ns is None else received_ns)

    def write_taxels(self, stamp_ns: int, part: str, frame: str, positions, slots, pressures, contact_ids,
                     received_ns: int | None = None) -> None:
        """One skin sample of a stream: the part's activated taxels (none: released); ``received_ns`` as in
        :meth:`write_joint_state`."""
        self._write_cloud(taxels_topic(part), stamp_ns, frame, taxels_array(slots, positions, pressures, contact_ids),
                          received_ns)

    def write_touch(self, stamp_ns: int, joint_names, joints, parts, fingertip: str | None = None) -> None:
        """One touch of a touch bag: its JointState, the fingertip that pressed it (a fingertip touch), then per
        touching part its taxels and contacts messages.

        ``parts``: ``(SkinPart, taxel points, contact points)`` per touching part
        (:func:`~nao_skin.formats.pointcloud.taxels_array`, :func:`~nao_skin.formats.pointcloud.contacts_array`);
        every message is stamped ``stamp_ns`` and the skin ones are in the part's chain-end frame.
        """
        self.write_joint_state(stamp_ns, joint_names, joints)
        if fingertip is not None:
            self._write(FINGERTIP_TOUCH_TOPIC, POINT_STAMPED,
                        self._PointStamped(header=self._header(stamp_ns, fingertip), point=self._Point(x=0.0, y=0.0,
                                                                                                      z=0.0)),
                        stamp_ns)
        for part, taxels, contacts in parts:
            self._write_cloud(taxels_topic(part.name), stamp_ns, part.parent_frame, taxels)
            self._write_cloud(contacts_topic(part.name), stamp_ns, part.parent_frame, contacts)


def detected_touch_messages(records, skin: SkinModel, part_names, joint_names, where: str | Path = "touches",
                            fingertips=()):
    """:func:`touch_messages` of touches a detector emitted (``part_names``, ``joint_names``: the detector's): a
    recorder's bag holds the same messages as one :func:`write_touch_bag` writes."""
    if not records:
        return iter(())
    return touch_messages(touchset_from_records(records, part_names, joint_names, fingertips=fingertips), skin, where)


def _stamp_ns(stamp: float, where: str) -> int:
    if not np.isfinite(stamp) or not 0 <= stamp < LAST_STAMP:
        raise DataError(f"{where}: stamp {float(stamp)!r} is not a time between 0 and {LAST_STAMP:.0f} s"
                        f" (a ROS message header holds int32 seconds: up to January 2038)")
    return int(round(float(stamp) * 1e9))


def default_bag_name(now=None) -> str:
    """Where a recording goes when nobody named it: ``nao_skin_touches_<date>_<time>`` (a new directory)."""
    from datetime import datetime

    return f"nao_skin_touches_{(now or datetime.now()):%Y%m%d_%H%M%S}"


def write_touch_bag(path: str | Path, touches: TouchSet, skin: SkinModel, storage: str = "sqlite3",
                    label: str | Path | None = None, source: str | Path | None = None) -> None:
    """Write a touch bag: per touch (in stamp order) one JointState and the touching parts' skin messages.

    Taxel positions are those of the nominal layout (what a skin driver sends);
    a contacts message lists the recorded skinManager contacts (id >= 0) with
    their recorded COP, the layout's geometric centre and normal, and the mean
    activation pressure; force and moment are not kept in a TouchSet (NaN). ``label``: the bag's name in
    messages (where ``path`` is a staging directory the user never sees). ``source``: where the touches were
    read, named instead when their stamps cannot be written (the input is what to correct, not the bag).
    """
    label = path if label is None else label
    origin = label if source is None else source
    first: dict = {}                        # a bad stamp is refused before anything is written
    for t in range(touches.n_touches):
        stamp_ns = _stamp_ns(touches.stamps[t], f"{origin}: touch {touches.keys[t]!r}")
        if stamp_ns in first:
            # a touch bag tells touches apart by their stamp: the reader would take the two as one touch
            raise DataError(f"{origin}: touches {touches.keys[first[stamp_ns]]!r} and {touches.keys[t]!r} would be"
                            f" written at one stamp ({stamp_ns // 1_000_000_000}.{stamp_ns % 1_000_000_000:09d} s)"
                            f" and read back as one touch; nothing written")
        first[stamp_ns] = t
    path = Path(path)
    check_new_bag(path, label)
    # written beside it and moved in whole: a run killed half-way (kill -9, a power cut) leaves no half bag to be
    # taken for a recording, only a hidden staging directory the next write there removes
    try:
        stage = staging_dir(path)
    except OSError as exc:
        raise DataError(f"{label}: cannot write the bag ({exc.strerror}); choose another place") from None
    staged = stage / path.name          # the storage file is named after the bag's directory
    try:
        try:
            with BagWriter(staged, storage, kind="touches") as bag:
                for touch in touch_messages(touches, skin, label):
                    bag.write_touch(*touch)
        except NaoSkinError as exc:     # said of the bag the user named (a full disk stays a DiskFull)
            exc.args = (str(exc).replace(str(staged), str(label)),)
            raise
        made_meanwhile = DataError(f"{label}: exists already (made meanwhile by another recording); a bag is"
                                   f" never overwritten")
        if path.exists() or path.is_symlink():
            raise made_meanwhile
        try:
            os.replace(staged, path)
        except OSError:             # made between the check and the move: a directory with files in it
            raise made_meanwhile from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def touch_messages(touches: TouchSet, skin: SkinModel, where: str | Path = "touches"):
    """The arguments of :meth:`BagWriter.write_touch` for every touch, in stamp order (see :func:`write_touch_bag`)."""
    parts = touch_parts(touches, skin)
    tip = touches.fingertip_of_touch
    for t in np.argsort(touches.stamps, kind="stable"):
        yield (_stamp_ns(touches.stamps[t], f"{where}: touch {touches.keys[t]!r}"), touches.joint_names,
               touches.joints[t], parts[t], touches.fingertips[tip[t]] if tip[t] >= 0 else None)


def touch_parts(touches: TouchSet, skin: SkinModel) -> list:
    """Per touch (index order) its touching parts' skin messages, as a skin driver sends them and a touch bag
    stores them: ``[(SkinPart, taxel points, contact points)]``
    (:func:`~nao_skin.formats.pointcloud.taxels_array`, :func:`~nao_skin.formats.pointcloud.contacts_array`).

    Taxel positions are the nominal layout's; a contacts message lists the recorded skinManager contacts
    (id >= 0) with their recorded COP, the layout's geometric centre and normal, and the mean activation
    pressure (NaN where a taxel's is unknown).
    """
    geom = contact_geometry(touches, skin, None)
    act_touch, act_part = touches.act_touch, touches.act_part
    act_cid = touches.contact_id[touches.act_contact]
    c_pressure = np.bincount(touches.act_contact, weights=np.nan_to_num(touches.act_pressure, nan=0.0),
                             minlength=len(touches.contact_touch)) / np.maximum(geom.n_taxels, 1)
    c_has_pressure = np.bincount(touches.act_contact, weights=np.isfinite(touches.act_pressure),
                                 minlength=len(touches.contact_touch)) == geom.n_taxels
    c_pressure = np.where(c_has_pressure, c_pressure, np.nan)
    # activations and contacts grouped per touch for slicing
    a_order = np.lexsort((act_part, act_touch))
    a_bounds = np.searchsorted(act_touch[a_order], np.arange(touches.n_touches + 1))
    c_order = np.lexsort((touches.contact_part, touches.contact_touch))
    c_bounds = np.searchsorted(touches.contact_touch[c_order], np.arange(touches.n_touches + 1))
    out = []
    for t in range(touches.n_touches):                 # one message group per touch: I/O, not maths
        acts = a_order[a_bounds[t]:a_bounds[t + 1]]
        cons = c_order[c_bounds[t]:c_bounds[t + 1]]
        parts = []
        for p in np.unique(act_part[acts]):
            part = skin.part(touches.part_names[p])
            a = acts[act_part[acts] == p]
            slots = touches.act_slot[a]
            c = cons[(touches.contact_part[cons] == p) & (touches.contact_id[cons] >= 0)]
            parts.append((part, taxels_array(slots, part.positions[slots], touches.act_pressure[a], act_cid[a]),
                          contacts_array(touches.contact_id[c], touches.contact_cop[c], geom.normal[c],
                                         geom.geo_center[c], pressure=c_pressure[c])))
        out.append(parts)
    return out


# ---------------------------------------------------------------------- reading
BAG_KINDS = ("touches", "stream")


def _event_config(kind: str, path: Path) -> EventConfig:
    """How the bag's events are read: a kind this version does not know is refused, never read as a stream
    (a touch bag read so loses the touches whose messages share a stamp)."""
    if kind not in BAG_KINDS:
        raise DataError(f"{path}: its metadata names the bag kind {kind!r} ({BAG_KIND_KEY}); this version reads"
                        f" {' and '.join(BAG_KINDS)}")
    return TOUCH_BAG_CONFIG if kind == "touches" else LIVE_CONFIG


def _custom_data(reader, path: Path) -> dict:
    """The bag's custom metadata: rosbags reads it from metadata.yaml, not from a storage file opened alone (its
    own copy of the metadata is read here then)."""
    custom = getattr(getattr(reader, "storage", None), "metadata", None)
    custom = getattr(custom, "custom", None)
    if custom is None and path.is_file():
        custom = (stored_metadata(path) or {}).get("custom_data")
    return dict(custom or {})


def _source_note(custom: dict, path: Path) -> str | None:
    """A line for every read of a bag recorded from the simulated robot: it is no recording of the robot (said as
    what the input is, :attr:`LoadReport.info`: a session that asked for the simulator expects it)."""
    if custom.get(SOURCE_KEY) == SIMULATED:
        return f"{path}: recorded from {SIMULATED}, not the robot"
    return None


def recorded_from(path: Path) -> str | None:
    """What a touch bag's recorder was fed (its metadata's ``nao_skin.recorded_from``), None when it does not say
    (a bag converted from a text file, one whose metadata is gone)."""
    source = _provisional_custom(path).get(SOURCE_KEY)
    return str(source) if source else None


def simulator_seed(path: Path) -> int | None:
    """The seed the simulated robot played into a record session's bag (its metadata's ``nao_skin.sim_seed``),
    None when it does not say (another source, a bag recorded before the seed was kept)."""
    text = str(_provisional_custom(path).get(SIM_SEED_KEY, "")).strip()
    return int(text) if text.isascii() and text.isdigit() else None


def continued_bags(path: Path) -> list:
    """The earlier sittings' bags a record session's bag continues (its metadata's ``nao_skin.continues``), as
    absolute paths: each where it lies relative to this bag as the session found them, when there is one there (a
    capture's folder moved or copied whole), else where the session found it; none when it says nothing."""
    custom = _provisional_custom(path)
    folder = (path if path.is_dir() else path.parent).parent

    def paths(key: str) -> list:
        try:
            value = json.loads(custom.get(key) or "[]")
        except ValueError:
            return []
        return [str(p) if isinstance(p, str) and p else "" for p in value] if isinstance(value, list) else []

    found, relative = paths(CONTINUES_KEY), paths(CONTINUES_RELATIVE_KEY)
    out = []
    for i, where in enumerate(found):
        moved = os.path.normpath(os.path.join(os.path.abspath(folder), relative[i])) if i < len(relative) \
            and relative[i] else ""
        if moved and (os.path.lexists(moved) or not where):
            out.append(moved)
        elif where:
            out.append(where)
    return out


def _provisional_custom(path: Path) -> dict:
    """The custom metadata of an unclosed bag's provisional metadata.yaml (beside the storage file, when that is
    what ``path`` names); none when it cannot be read."""
    try:
        info = bag_metadata(path if path.is_dir() else path.parent)
        return dict(info.get("custom_data") or {})
    except Exception:  # noqa: BLE001 - no or unreadable metadata: nothing says it is a touch bag
        return {}


def _is_read(topic: str, msgtype: str) -> bool:
    """A topic touches are read from, with its message type."""
    return ((topic == JOINT_STATES_TOPIC and msgtype == JOINT_STATE)
            or (topic == FINGERTIP_TOUCH_TOPIC and msgtype == POINT_STAMPED)
            or (msgtype == POINT_CLOUD and skin_topic(topic) is not None))


def _of_unknown_part(topic: str, skin: SkinModel) -> bool:
    return topic not in (JOINT_STATES_TOPIC, FINGERTIP_TOUCH_TOPIC) and skin_topic(topic)[0] not in skin.parts


def _skip_unknown_parts(report: LoadReport, path: Path, unknown: dict, skin: SkinModel) -> None:
    for topic, count in unknown.items():
        report.skip("unknown skin part", f"{path}: topic '{topic}': skin part '{skin_topic(topic)[0]}'"
                                         f" is not configured ({', '.join(skin.parts)}); {count} messages skipped",
                    count=count)


def _skip_other_type(report: LoadReport, path: Path, conn) -> None:
    """Say a topic touches are read from whose messages are of another type (another tool's, a mistake)."""
    expected = (JOINT_STATE if conn.topic == JOINT_STATES_TOPIC else POINT_STAMPED if conn.topic == FINGERTIP_TOUCH_TOPIC
                else POINT_CLOUD if skin_topic(conn.topic) is not None else None)
    if expected is not None and conn.msgtype != expected:
        report.skip("unexpected message type", f"{path}: topic '{conn.topic}' holds {conn.msgtype}, not {expected};"
                                               f" its {conn.msgcount} messages skipped", count=conn.msgcount)


def _skip_bad(report: LoadReport, exc: DataError) -> None:
    report.skip(getattr(exc, "reason", "bad message"), str(exc), part=getattr(exc, "part", None))


def _skip_unread(report: LoadReport, path: Path, wanted: list, read: Counter) -> None:
    """What metadata.yaml lists and the storage file did not give: a file that ends early without an error
    (an mcap whose chunk is broken), or, when every other topic is there whole, a topic the file does not
    hold at all (its storage lists other topics)."""
    listed, got = sum(conn.msgcount for conn in wanted), sum(read[conn.id] for conn in wanted)
    absent = [conn for conn in wanted if conn.msgcount and not read[conn.id]]
    if absent and all(read[conn.id] >= conn.msgcount for conn in wanted if conn not in absent):
        for conn in absent:
            report.skip("topic not in storage", f"{path}: {conn.topic} ({conn.msgtype}): metadata.yaml lists"
                                                f" {conn.msgcount} messages, the storage file holds none of them",
                        count=conn.msgcount)
        return
    if got < listed:
        report.skip("truncated bag", f"{path}: {got} of the {listed} messages its metadata lists could be read; the"
                                     f" storage file is damaged, the rest is lost", count=listed - got)


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
    return GrowingBag(path, skin, config, max_neighbor_dist, cluster).read()


class GrowingBag:
    """A bag read again and again while it is being recorded (the live calibrate node's input).

    Each :meth:`read` returns what :func:`read_touches` returns for the bag as
    it is at that moment, but decodes only the messages written since the
    previous read: what was committed before is kept as touches, and the
    event detector's state after it is kept too (the touch that the last
    messages may still continue is finished on a copy). A closed bag, and a
    storage file replaced or rewritten meanwhile, are read whole.
    """

    def __init__(self, path: str | Path, skin: SkinModel, config: EventConfig | None = None,
                 max_neighbor_dist: float = DEFAULT_MAX_NEIGHBOR_DIST, cluster: bool = True):
        self.path = Path(path)
        self.skin, self.config = skin, config
        self.max_neighbor_dist, self.cluster = max_neighbor_dist, cluster
        self._cursor = None
        self._feed: _Feed | None = None
        self._touches: TouchSet | None = None    # of the feed's records so far, clustered
        self._source: str | None = None          # the note of a bag recorded from the simulated robot

    def read(self) -> tuple:
        """``(TouchSet, LoadReport)`` of everything the bag holds now."""
        from rosbags.rosbag2 import Reader

        check_storage_files(self.path)
        # metadata.yaml lists the messages only once the bag is closed: read an unclosed sqlite3 file itself
        bag = unclosed_sqlite(self.path) or provisional_mcap(self.path)
        if bag is None:
            try:
                reader = Reader(self.path)
                reader.open()
            except Exception as exc:  # noqa: BLE001 - rosbags, sqlite and yaml all raise their own types
                bag = cut_mcap(self.path, exc) or cut_sqlite(self.path, exc)
                if bag is None:
                    raise DataError(f"{self.path}: cannot open as a rosbag2 ({one_line(exc)})") from None
            else:
                self._cursor = self._feed = self._touches = None
                return self._read_closed(reader)
        tail = bag.since(self._cursor)
        if self._feed is None or tail.restarted:
            custom = bag.custom_data or _provisional_custom(self.path)
            config = self.config or _event_config(str(custom.get(BAG_KIND_KEY, "stream")), self.path)
            self._source = _source_note(custom, self.path)
            self._feed = _Feed(self.path, self.skin, config, LoadReport(str(self.path)))
            self._touches = None
        self._cursor = tail.cursor
        self._feed.add(tail.committed)
        done = self._touches.n_touches if self._touches is not None else 0
        self._touches = self._finish(self._feed, self._feed.records[done:], self._touches)
        now = self._feed.fork()
        ends = now.add(tail.provisional)
        now.finish()
        extra = now.records[len(self._feed.records):]
        report = now.report
        _skip_unknown_parts(report, self.path, now.unknown, self.skin)
        lost = bag.lost(now.n_msgs, ends)
        if lost is not None:
            report.skip(*lost)
        touches = now.apart(self._finish(now, extra, self._touches))
        now.account(touches)
        note = bag.note(now.n_msgs, touches.n_touches)
        if note is not None:
            report.notes.append(note)
        report.info += [line for line in (bag.info(now.n_msgs, touches.n_touches), self._source) if line is not None]
        return touches, report

    def _finish(self, feed: "_Feed", records: list, before: TouchSet | None) -> TouchSet:
        """``before`` and the touches of ``feed``'s ``records`` after it, clustered."""
        touches = touchset_from_records(records, feed.detector.part_names, feed.detector.joint_names,
                                        fingertips=feed.detector.fingertip_names)
        if self.cluster:
            touches = cluster_contacts(touches, self.skin, None, self.max_neighbor_dist)
        return touches if before is None else TouchSet.concatenate([before, touches])

    def _read_closed(self, reader) -> tuple:
        report = LoadReport(str(self.path))
        try:
            custom = _custom_data(reader, self.path)
            feed = _Feed(self.path, self.skin, self.config or _event_config(str(custom.get(BAG_KIND_KEY, "stream")),
                                                                            self.path), report)
            source = _source_note(custom, self.path)
            if source is not None:
                report.info.append(source)
            wanted, unknown = [], {}
            for conn in reader.connections:
                if not _is_read(conn.topic, conn.msgtype):
                    _skip_other_type(report, self.path, conn)
                    continue
                if _of_unknown_part(conn.topic, self.skin):
                    unknown[conn.topic] = conn.msgcount
                else:
                    wanted.append(conn)
            _skip_unknown_parts(report, self.path, unknown, self.skin)
            read: Counter = Counter()       # messages read per connection
            try:
                for conn, _, raw in reader.messages(connections=wanted):
                    read[conn.id] += 1
                    feed.add([(conn.topic, conn.msgtype, raw)])
            except Exception as exc:  # noqa: BLE001 - a broken file raises whatever its storage library raises
                report.skip("truncated bag", f"{self.path}: unreadable after {feed.n_msgs} messages"
                                             f" ({one_line(exc)}); the rest of the bag is lost")
            else:
                _skip_unread(report, self.path, wanted, read)
            feed.finish()
        finally:
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a broken bag must not hide what was read
                pass
        touches = feed.apart(self._finish(feed, feed.records, None))
        feed.account(touches)
        return touches, report


class _Feed:
    """Messages of one bag fed in order to an event detector, with what its load report needs."""

    def __init__(self, path: Path, skin: SkinModel, config: EventConfig, report: LoadReport):
        self.path, self.skin, self.report = path, skin, report
        self.detector = EventDetector.for_skin(skin, config)
        # a stream bag holds each topic as its recorder got it, and a recorder held up gets the topics' backlogs
        # one after another: read in the order of their stamps, as the live recorder reads them (a touch bag is
        # written in order); the clock that says how long a message waited is the newest stamp read, moved at
        # most CLOCK_STEP_S per message (one message stamped far ahead must not make every later one wait for
        # a quiet stream to the end of the bag)
        self.in_order = InOrder() if config.skin_tolerance > 0 else None
        self.clock = float("-inf")
        self.store = _typestore()
        self.records: list = []
        self.n_msgs = 0
        self.unknown = Counter()        # messages of topics whose part the skin does not have
        # exact stamps (a touch bag): stamp -> joint states at it, one per touch (a stream's are not counted:
        # a recording of hours holds millions)
        self.joint_states = Counter() if config.skin_tolerance == 0 else None

    def add(self, messages) -> str:
        """Feed ``(topic, msgtype, data)`` up to a ``(None, why, None)``; returns how they end."""
        for topic, msgtype, data in messages:
            if topic is None:
                return msgtype
            if not _is_read(topic, msgtype):
                continue
            if _of_unknown_part(topic, self.skin):
                self.unknown[topic] += 1
                continue
            self.n_msgs += 1
            try:
                stamp, call = _decoded(self.store, topic, msgtype, data, self.skin, self.path, self.joint_states)
            except DataError as exc:
                _skip_bad(self.report, exc)
                continue
            if self.in_order is None:
                self._detect([call])
            else:
                self.clock = stamp if self.clock == float("-inf") else max(self.clock,
                                                                           min(stamp, self.clock + CLOCK_STEP_S))
                self._detect(self.in_order.push(topic, stamp, self.clock, call))
        return "ends cleanly"

    def _detect(self, calls) -> None:
        for method, args in calls:
            self.records += getattr(self.detector, method)(*args)

    def finish(self) -> None:
        """The end of the messages: what still waited for another stream, then for joint states."""
        if self.in_order is not None:
            self._detect(self.in_order.drain())
        self.records += self.detector.flush()

    def fork(self) -> "_Feed":
        """A copy to feed and finish while this one goes on (the type store is shared: it never changes)."""
        other = copy.copy(self)
        other.detector, other.report = copy.deepcopy(self.detector), copy.deepcopy(self.report)
        other.in_order = copy.deepcopy(self.in_order)
        other.records, other.unknown = list(self.records), Counter(self.unknown)
        other.joint_states = None if self.joint_states is None else Counter(self.joint_states)
        return other

    def apart(self, touches: TouchSet) -> TouchSet:
        """``touches`` without those whose stamp more than one touch of a touch bag was written at.

        Read with exact stamps (a touch bag), every touch is one joint state and its skin messages at one
        stamp, so touches sharing a stamp are read as one touch of all their parts together: a bag whose
        stamps were never set (all 0) would be one touch of every part pair. Those are skipped and said.
        """
        shared = sorted(s for s, n in (self.joint_states or {}).items() if n > 1)
        if not shared:
            return touches
        lost = sum(self.joint_states[s] for s in shared)
        self.report.skip("touches at one stamp", f"{self.path}: {lost} touches were written at {len(shared)}"
                                                 f" stamps shared with another touch (the first at {shared[0]:.9f}"
                                                 f" s): a touch bag tells its touches apart by their stamps, so"
                                                 f" they cannot be read (were its stamps unset or rewritten?)",
                         count=lost)
        return touches.subset(~np.isin(touches.stamps, shared))

    def account(self, touches: TouchSet) -> None:
        """The load report of these messages, ``touches`` being what they gave."""
        for reason, count in self.detector.drops().items():
            self.report.skipped[reason] += count
        self.report.messages.extend(f"{self.report.source}: {note}" for note in self.detector.notes)
        if touches.n_touches == 0 and self.n_msgs and not self.detector.counts and not self.report.skipped:
            # nothing was dropped, so nothing was ever a moment of two parts pressed together: say why
            tolerance = self.detector.config.skin_tolerance
            when = "at one stamp" if tolerance == 0 else f"within {tolerance:g} s of each other"
            pressed = self.detector.n_pressed
            self.report.notes.append(
                f"{self.report.source}: " + (f"of its {pressed} skin samples with a taxel on, none met another part's"
                                             f" {when}: nothing in it is a self-touch" if pressed else
                                             "none of its skin samples has a taxel on: nothing was pressed")
                + (" (a touch bag stores each touch's messages at one stamp: are its stamps rewritten?)"
                   if tolerance == 0 and pressed else ""))
        self.report.n_read = self.n_msgs
        self.report.n_loaded = touches.n_touches
        self.report.unit = "messages"


def _decoded(store, topic: str, msgtype: str, raw, skin: SkinModel, path: Path,
             joint_states: Counter | None) -> tuple:
    """One message decoded: ``(stamp, (the detector's method, its arguments))`` (a joint state counted at its
    stamp in ``joint_states``, when given); DataError names bag, topic and stamp."""
    try:
        msg = store.deserialize_cdr(raw, msgtype)
    except Exception as exc:  # noqa: BLE001 - CDR decoding raises assorted errors on bad bytes
        raise DataError(f"{path}: topic '{topic}': undecodable {msgtype} ({one_line(exc)})") from None
    stamp = header_seconds(msg.header.stamp, f"{path}: topic '{topic}'")
    where = f"{path}: topic '{topic}' at {stamp:.9f}"
    if topic == JOINT_STATES_TOPIC:
        if joint_states is not None:
            joint_states[stamp] += 1
        return stamp, ("add_joint_state", (stamp, msg.name, msg.position))
    if topic == FINGERTIP_TOUCH_TOPIC:
        return stamp, ("add_fingertip", (stamp, msg.header.frame_id))
    part, what = skin_topic(topic)
    if what == "contacts":
        return stamp, ("add_contacts", (stamp, part, *read_contacts(msg, skin.parts[part], where)))
    slots, pressures, contacts = read_taxels(msg, skin.parts[part], where)
    return stamp, ("add_skin", (stamp, part, slots.tolist(), pressures.tolist(), contacts.tolist()))
