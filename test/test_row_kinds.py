"""One door for every kind of row (calibration/rows.py): each registered kind builds its rows from one fit context,
and rows of different kinds, a fingertip's beside two skins', assembled into one pairing are what each kind gives
alone."""
from functools import partial

import numpy as np
import pytest

from nao_skin.calibration.context import FitContext, SkinPair
from nao_skin.calibration.fingertip import FingertipScene, fingertip_scene
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import KIND_COP, KIND_FINGERTIP, chain_end_poses
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.calibration.rows import ROW_KINDS, build_rows, select_rows
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate

FIELDS = ("row_touch", "row_kind", "row_parts", "term_row", "term_part", "term_slot", "term_weight", "distance",
          "row_normal", "row_offset", "row_fingertip", "row_direction")


@pytest.fixture(scope="module")
def mixed(default_skin):
    """Two hands on the torso and a fingertip pressing it."""
    return simulate(default_skin, load_params("fingertip-mixed", {"n_touches": 25}), seed=1)


def _pairs(ctx):
    names = ctx.touches.part_names
    skin_pairs = [ctx.skin_pair(names.index(hand), names.index("torso")) for hand in ("r_hand", "l_hand")]
    return skin_pairs + [fingertip_scene(ctx, "r_finger", "torso")]


def _same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), name


def test_every_kind_builds_its_rows_through_the_door(mixed, default_skin):
    """Each registered kind gives rows of its own kind on the pairs it is for, and all kinds at once give each
    kind's rows as it gives them alone."""
    ctx = FitContext.of(mixed.touches, default_skin, mixed.truth)
    pairs = _pairs(ctx)
    assert {row_kind.on for row_kind in ROW_KINDS} == {SkinPair, FingertipScene}
    everything = build_rows(ctx, pairs, [row_kind.kind for row_kind in ROW_KINDS])
    for row_kind in ROW_KINDS:
        alone = build_rows(ctx, pairs, (row_kind.kind,))
        assert alone.n_rows > 0, row_kind
        assert np.all(alone.row_kind == row_kind.kind)
        sides = {tuple(p.parts) for p in pairs if isinstance(p, row_kind.on)}
        assert set(map(tuple, alone.row_parts.tolist())) <= sides
        assert np.all(np.diff(alone.row_touch) >= 0)     # a pairing's rows go by touch
        _same(select_rows(everything, (row_kind.kind,)), alone)


def test_a_fingertip_row_beside_cop_rows_is_the_row_it_is_alone(mixed, default_skin):
    touches, truth = mixed.touches, mixed.truth
    ctx = FitContext.of(touches, default_skin, truth)
    pairs = _pairs(ctx)
    together = build_rows(ctx, pairs, (KIND_COP, KIND_FINGERTIP))
    assert set(np.unique(together.row_kind)) == {KIND_COP, KIND_FINGERTIP}
    poses = partial(chain_end_poses, touches, default_skin)

    def residuals(pairing):
        model = ResidualModel(default_skin, poses, pairing, touches.part_names,
                              ParameterLayout(default_skin, touches.part_names), truth, fabric=0.001,
                              fingertip_names=touches.fingertips)
        return model.residuals(truth)

    mixed_rows = residuals(together)
    for kind, pair_list in ((KIND_COP, pairs[:2]), (KIND_FINGERTIP, pairs[2:])):
        alone = build_rows(ctx, pair_list, (kind,))
        np.testing.assert_allclose(mixed_rows[together.row_kind == kind], residuals(alone), rtol=0, atol=1e-15)
