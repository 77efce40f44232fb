"""Skin activation of a simulated self-touch, from the geometry of the true skin.

At a solved pose the two skins face each other across the fabric gap. The
hand does not press evenly (knuckles, fabric folds): pressure comes through a
few *spots* scattered over a footprint around the contact point. A taxel of
either part fires when it lies under a spot and the other part's surface is
within ``gap + reach`` of it (a compliant fabric spreads the load a little);
its pressure falls off with that distance and away from the spot centre.

Each spot is one skin *event*: spots come and go while the hand is pressed,
skinManager reports each as its own contact, and the recorder collects the
contacts of the whole press into one touch. That is why a real touch has
several contacts per part, often with neighbouring taxels in different
contacts (measured on the real recording: ~3 contacts per part and touch,
the closest taxels of two contacts typically one lattice step apart).
Within an event, taxels are grouped by neighbour distance as skinManager does
(:func:`nao_skin.touch.contacts.cluster_labels`).
"""
from __future__ import annotations

import numpy as np

from nao_skin import se3
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.press import (PRESSURE_MAX, contact_frame, nearest_lateral, press_pressure, separation,
                                  take_columns)

CHUNK = 256              # touches per vectorised block (bounds memory at ~N * 96 * 96 floats)
SPOT_SEPARATION = 0.6    # spot centres at least this times the sum of their radii apart


def taxels_in_base(skin: SkinModel, part: str, q: np.ndarray, truth: SkinCalibration):
    """True positions and normals ``(N, S, 3)`` of the present taxels, and their slots ``(S,)``."""
    sp = skin.parts[part]
    pos, nor = sp.taxel_positions(truth.parts.get(part))
    slots = sp.slots
    end = skin.robot.fk(sp.chain, q)[:, None]
    return se3.transform_points(end, pos[slots][None]), se3.rotate_vectors(end, nor[slots][None]), slots


def draw_spots(n: int, p, rng: np.random.Generator):
    """Per touch: spot centres ``(N, K, 2)`` in the contact plane, radii ``(N, K)`` (0 = no spot)."""
    k_max = int(p.pressure_spots[1])
    count = rng.integers(int(p.pressure_spots[0]), k_max + 1, size=n)
    footprint = rng.uniform(*p.footprint_radius, size=(n, 1))
    r = footprint * np.sqrt(rng.uniform(size=(n, k_max)))
    phi = rng.uniform(0, 2 * np.pi, size=(n, k_max))
    centres = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=2)
    centres[:, 0] = 0.0                      # the solved contact point always presses
    radius = rng.uniform(*p.spot_size, size=(n, k_max))
    radius[np.arange(k_max)[None, :] >= count[:, None]] = 0.0
    # spots do not overlap much: one that would is dropped (a loop over <= K spots, vectorised over N)
    for k in range(1, k_max):
        d = np.linalg.norm(centres[:, :k] - centres[:, k:k + 1], axis=2)
        crowded = np.any((radius[:, :k] > 0) & (d < SPOT_SEPARATION * (radius[:, :k] + radius[:, k:k + 1])), axis=1)
        radius[crowded, k] = 0.0
    return centres, radius


def fire(skin: SkinModel, truth: SkinCalibration, hand: str, target: str, q: np.ndarray,
         contact: np.ndarray, normal: np.ndarray, gap: np.ndarray, p, rng: np.random.Generator):
    """Activations of both parts for N touches (true joints ``q``, true skin).

    ``contact`` is the midpoint between the two touching skin surfaces and
    ``normal`` the target's outward normal there (base frame). Returns flat
    arrays ``(touch, side, slot, pressure, event)`` with side 0 = hand,
    1 = target, and ``event`` the spot that pressed the taxel.
    """
    n = len(q)
    if n == 0:   # no pose of this pair was found (e.g. a narrow planar band): nothing fires
        empty = np.zeros(0, dtype=int)
        return empty, empty, empty, np.zeros(0), empty
    centres, radius = draw_spots(n, p, rng)
    reach = rng.uniform(*p.press_reach, size=n)
    out = []
    sides = []
    for side, part in enumerate((hand, target)):
        pos, nor, slots = taxels_in_base(skin, part, q, truth)
        lat, height = contact_frame(pos, contact, normal)
        # only the surface facing the other part can stand for it (not the far side of the hand)
        facing = np.einsum("nsk,nk->ns", nor, normal) * (1.0 if side == 1 else -1.0) > 0.0
        cols = nearest_lateral(lat)
        sides.append((take_columns(lat, cols), take_columns(height, cols), cols, slots, take_columns(facing, cols)))
    for side in (0, 1):
        lat, height, cols, slots, _ = sides[side]
        o_lat, o_height, _, _, o_facing = sides[1 - side]
        for start in range(0, n, CHUNK):
            sl = slice(start, min(start + CHUNK, n))
            # the other part's surface height under each taxel: its laterally nearest taxel
            sep, _ = separation(lat[sl], height[sl], o_lat[sl], o_height[sl], o_facing[sl], touched=side == 1)
            # under which spot, and how central
            sd = np.linalg.norm(lat[sl][:, :, None] - centres[sl][:, None], axis=3)
            rad = radius[sl][:, None]
            closeness = np.where(rad > 0, 1.0 - (sd / np.where(rad > 0, rad, 1.0)) ** 2, -1.0)
            spot = np.argmax(closeness, axis=2)
            central = np.take_along_axis(closeness, spot[..., None], axis=2)[..., 0]
            slack = sep - gap[sl, None]
            depth = 1.0 - slack / reach[sl, None]
            firing = (central > 0) & (depth > 0)
            t, s = np.nonzero(firing)
            pressure = press_pressure(depth[t, s], central[t, s])
            out.append((t + start, np.full(len(t), side), slots[cols[sl][t, s]], np.round(pressure), spot[t, s]))
    touch, side, slot, pressure, event = (np.concatenate(a) for a in zip(*out))
    order = np.lexsort((slot, side, touch))
    return touch[order], side[order], slot[order], pressure[order], event[order]


def patch_activation(skin: SkinModel, truth: SkinCalibration, part: str, q: np.ndarray,
                     eligible, rng: np.random.Generator):
    """A blob of activation on ``part`` where something else presses it (e.g. the experimenter's hand).

    Per touch a centre taxel is drawn among those for which
    ``eligible(positions, normals)`` (``(N, S, 3)`` base frame -> ``(N, S)``
    bool) holds; taxels within 8..14 mm of it fire. Returns ``(touch, slot, pressure)``.
    """
    pos, nor, slots = taxels_in_base(skin, part, q, truth)
    n = len(q)
    weight = eligible(pos, nor).astype(float) + 1e-9
    cum = np.cumsum(weight, axis=1)
    pick = np.argmax(cum >= rng.uniform(size=(n, 1)) * cum[:, -1:], axis=1)
    centre = pos[np.arange(n), pick]
    dist = np.linalg.norm(pos - centre[:, None], axis=2)
    radius = rng.uniform(0.008, 0.014, size=(n, 1))
    t, s = np.nonzero(dist <= radius)
    pressure = np.round(np.clip(PRESSURE_MAX * (1.0 - (dist[t, s] / radius[t, 0]) ** 2), 1.0, PRESSURE_MAX))
    return t, slots[s], pressure
