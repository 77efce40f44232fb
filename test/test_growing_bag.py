"""A recording read again and again while it is written (GrowingBag, the live calibrate node's input).

Every read must give exactly what a whole read of the bag gives at that
moment (read_touches: touches, skips, notes), while decoding only the
messages written since the previous read. The bags are real: written by
BagWriter(live=True) as the pairing recorder writes them, flushed batch by
batch, never closed (the lock names this process, so they read as open);
an mcap file is also cut at arbitrary bytes, as a flush in progress or a
killed recorder leaves it.
"""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from nao_skin.errors import BagMoved
from nao_skin.formats import bag as bagmod
from nao_skin.formats.bag import BagWriter, GrowingBag, read_touches
from nao_skin.model.skin import load_skin
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from recorded_touches import write_recorded

SEED, PER_PAIR = 3, 10


@pytest.fixture(scope="module")
def played():
    skin = load_skin()
    touches = simulate(skin, load_params("default", {"n_touches": PER_PAIR}), SEED).touches
    return skin, touches.subset(np.argsort(touches.stamps, kind="stable"))


def assert_same_read(got: tuple, want: tuple) -> None:
    (g, g_rep), (w, w_rep) = got, want
    assert g.n_touches == w.n_touches
    assert g.part_names == w.part_names and g.joint_names == w.joint_names and g.keys == w.keys
    for name in ("stamps", "joints", "contact_touch", "contact_part", "contact_id", "contact_cop",
                 "act_contact", "act_slot", "act_pressure"):
        np.testing.assert_array_equal(getattr(g, name), getattr(w, name), err_msg=name)
    assert g_rep.summary() == w_rep.summary()
    assert g_rep.messages == w_rep.messages and g_rep.notes == w_rep.notes and g_rep.info == w_rep.info


@pytest.fixture
def decoded(monkeypatch):
    """How many messages the bag module decodes (each goes through ``_decoded`` once)."""
    count = [0]
    original = bagmod._decoded

    def counting(*args, **kwargs):
        count[0] += 1
        return original(*args, **kwargs)

    monkeypatch.setattr(bagmod, "_decoded", counting)
    return count


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_each_read_equals_a_whole_read_and_decodes_only_new_messages(played, tmp_path, storage, decoded):
    skin, touches = played
    path = tmp_path / "rec"
    follower = GrowingBag(path, skin)
    batches = np.split(np.arange(touches.n_touches), [1, 4, 5, 13, 21, 34])
    with BagWriter(path, storage, kind="touches", live=True) as bag:
        written = follower_decoded = 0
        for rows in batches:
            write_recorded(bag, skin, touches, rows)
            bag.flush()
            written += len(rows)
            before = decoded[0]
            got = follower.read()
            new = decoded[0] - before
            follower_decoded += new
            assert_same_read(got, read_touches(path, skin))
            assert got[0].n_touches == written
            assert "still open" in got[1].info[-1] and not got[1].notes
            # the follower decoded this batch's messages, not the bag's: 1 joint state + 1-2 skin parts per touch
            assert len(rows) <= new <= 3 * len(rows)
        assert follower_decoded == got[1].n_read     # each message once; whole reads decode the bag each time
    # closed: the follower reads the closed bag like any reader
    assert_same_read(follower.read(), read_touches(path, skin))
    assert follower.read()[0].n_touches == touches.n_touches


def test_an_mcap_file_cut_anywhere_reads_as_a_whole_read_does(played, tmp_path):
    """Cut at every few bytes (inside chunks, headers, records): the committed touches are kept, the rest is
    read again when its bytes arrive, and the lines say the same as a whole read's."""
    skin, touches = played
    src = tmp_path / "src"
    with BagWriter(src, "mcap", kind="touches", live=True) as bag:
        for rows in np.array_split(np.arange(touches.n_touches), 8):
            write_recorded(bag, skin, touches, rows)
            bag.flush()
        data = next(src.glob("*.mcap")).read_bytes()
        growing = tmp_path / "growing"
        growing.mkdir()
        for name in ("metadata.yaml", "recording.lock"):
            shutil.copy(src / name, growing / name)
        file = growing / next(src.glob("*.mcap")).name
        follower = GrowingBag(growing, skin)
        cuts = sorted(set(np.linspace(0, len(data), 60).astype(int)) | {8, 9, 17, len(data) - 1})
        kept = 0
        for lo, hi in zip([0] + cuts, cuts):
            with open(file, "ab") as f:          # appended, as a recorder writes: the same file throughout
                f.write(data[lo:hi])
            got = follower.read()
            assert_same_read(got, read_touches(growing, skin))
            assert got[0].n_touches >= kept          # nothing read before is ever lost
            kept = got[0].n_touches
        assert kept == touches.n_touches


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_replaced_recording_is_read_from_its_start(played, tmp_path, storage):
    skin, touches = played
    path, other = tmp_path / "rec", tmp_path / "other"
    first = BagWriter(path, storage, kind="touches", live=True).__enter__()   # never closed: it is replaced
    write_recorded(first, skin, touches, range(20))
    first.flush()
    follower = GrowingBag(path, skin)
    assert follower.read()[0].n_touches == 20
    suffix = {"mcap": "*.mcap", "sqlite3": "*.db3"}[storage]
    with BagWriter(other, storage, kind="touches", live=True) as bag:
        write_recorded(bag, skin, touches, range(5, 12))
        bag.flush()
        file = next(path.glob(suffix))
        file.unlink()
        shutil.copy(next(other.glob(suffix)), file)     # another file under the old name, fewer touches
        got = follower.read()
        assert_same_read(got, read_touches(path, skin))
        np.testing.assert_array_equal(got[0].stamps, touches.stamps[5:12])


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("how, when", [("removed", "flush"), ("moved", "flush"), ("replaced", "flush"),
                                       ("removed", "close"), ("replaced", "close")])
def test_a_bag_whose_directory_goes_while_recording_is_copied_out_and_what_took_its_name_left_alone(
        played, tmp_path, storage, how, when):
    """``rm -rf`` of the bag being recorded went on into a deleted file and ended saying the touches were kept;
    a directory put in its place got this session's metadata.yaml. Now every touch so far is copied out through
    the files still open, the bag is abandoned, and the line says where the touches are."""
    skin, touches = played
    path = tmp_path / "rec"
    other = tmp_path / "other"       # another, closed recording that takes the name
    with BagWriter(other, storage, kind="touches") as bag:
        write_recorded(bag, skin, touches, np.arange(3))
    theirs = {f.name: f.read_bytes() for f in other.iterdir()}
    with pytest.raises(BagMoved) as err:
        with BagWriter(path, storage, kind="touches", live=True) as bag:
            write_recorded(bag, skin, touches, np.arange(10))
            bag.flush()
            if how == "removed":
                shutil.rmtree(path)
            else:
                path.rename(tmp_path / "elsewhere")
                if how == "replaced":
                    shutil.copytree(other, path)
            write_recorded(bag, skin, touches, np.arange(10, 16))   # sqlite3: raises here
            if when == "flush":
                bag.flush()
                pytest.fail("the flush went on into a directory that is not the bag's")
    rescued = tmp_path / "rec.rescued"
    assert str(err.value) == (f"{path}: the bag's directory was removed, moved or replaced while recording; every"
                              f" touch written so far is copied to {rescued} (nao-skin reads it: nao-skin stats"
                              f" {rescued}); recording stopped")
    # sqlite3 takes no more touches once its directory is gone (its journal would be made there)
    kept = 16 if storage == "mcap" else 10
    got, report = read_touches(rescued, skin)
    assert got.n_touches == kept
    np.testing.assert_allclose(got.stamps, np.sort(touches.stamps[:kept]), rtol=0, atol=1e-6)
    # read as the copy it is, with nothing lost (it was read as a damaged file whose rest is lost)
    assert not report.skipped, report.lines()
    assert any(note.startswith(f"{rescued}: the copy of {path} its recorder made when that bag's directory was"
                               f" removed, moved or replaced while recording") and f"{kept} touches" in note
               for note in report.notes), report.lines()
    if how == "replaced":
        assert {f.name: f.read_bytes() for f in path.iterdir()} == theirs
    if how != "removed":              # the moved original holds them too
        assert read_touches(tmp_path / "elsewhere", skin)[0].n_touches == kept


def test_the_salvage_limit_counts_what_a_read_reads_and_reads_nothing_whole_beyond_it(played, tmp_path,
                                                                                       monkeypatch):
    """An mcap file read from itself is refused when more than MAX_SALVAGE_BYTES would be read at once (a
    damaged multi-GB file: a MemoryError before). A live recording's follower reads only what is new: it
    went on past the limit, which first counted the whole file; and the file's own metadata was looked for
    by reading the whole file before the limit was checked. The limit is made small here."""
    from nao_skin.errors import DataError
    from nao_skin.formats import salvage

    skin, touches = played
    path = tmp_path / "rec"
    follower = GrowingBag(path, skin)
    with BagWriter(path, "mcap", kind="touches", live=True) as bag:
        write_recorded(bag, skin, touches, np.arange(8))
        bag.flush()
        (file,) = path.glob("*.mcap")
        monkeypatch.setattr(salvage, "MAX_SALVAGE_BYTES", file.stat().st_size + 10)
        assert follower.read()[0].n_touches == 8
        for start in (8, 16, 24):            # the file grows past the limit, each read stays under it
            write_recorded(bag, skin, touches, np.arange(start, start + 8))
            bag.flush()
            assert follower.read()[0].n_touches == start + 8
        assert file.stat().st_size > salvage.MAX_SALVAGE_BYTES
        # read whole, the same file is over the limit: one line, and not a byte of it read whole first
        (tmp_path / "alone").mkdir()
        alone = tmp_path / "alone" / "rec_0.mcap"
        shutil.copy(file, alone)
        real_read_bytes = type(alone).read_bytes

        def guarded(self):
            assert self.name != alone.name, "read whole past the limit"
            return real_read_bytes(self)

        monkeypatch.setattr(type(alone), "read_bytes", guarded)
        with pytest.raises(DataError, match="rec_0.mcap is larger than 0 GiB and its bag does not open"):
            read_touches(tmp_path / "alone", skin)
