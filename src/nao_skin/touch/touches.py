"""Touches as flat arrays: the one data structure capture, simulation and calibration share.

A *touch* is a moment when two (or more) skin parts fire together (a self-touch), or when one part fires
under a fingertip of the robot (a fingertip touch: ``touch_fingertip`` names which), with the robot's joint
angles at that moment. Its skin data is a list of skinManager
*contacts* (clusters of activated taxels), each on one part. Everything is
stored flat ("struct of arrays") so that re-pairing and residuals run
vectorised over all touches: an activation knows its contact, a contact its
touch and part.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np


@dataclass
class TouchSet:
    part_names: tuple                 # skin part names; contact_part indexes into it
    joint_names: tuple                # NAOqi names; columns of ``joints``
    stamps: np.ndarray                # (N,) seconds (float64)
    keys: list                        # (N,) original touch ids (legacy keys, bag stamps)
    joints: np.ndarray                # (N, J) radians
    contact_touch: np.ndarray         # (C,) int: touch row of each contact
    contact_part: np.ndarray          # (C,) int: index into part_names
    contact_id: np.ndarray            # (C,) int: skinManager contactId (-1 unknown)
    contact_cop: np.ndarray           # (C, 3) recorded COP, part local frame (NaN unknown)
    act_contact: np.ndarray           # (A,) int: contact row of each activated taxel
    act_slot: np.ndarray              # (A,) int: taxel slot on its part
    act_pressure: np.ndarray          # (A,) float: pressure (NaN when the source has none)
    labels: dict = field(default_factory=dict)   # optional per-touch arrays, e.g. simulator truth
    fingertips: tuple = ()            # fingertip names (robot config); touch_fingertip indexes into it
    # (N,) int: the fingertip that pressed each touch, -1 for a self-touch; None: every touch a self-touch
    touch_fingertip: np.ndarray | None = None
    # what calibration derives from these touches again and again (FK, pair subsets, COP weights):
    # kept with the touch set, so it lives as long as the touches and is never another set's
    _derived: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    # ------------------------------------------------------------------ derived
    @property
    def n_touches(self) -> int:
        return len(self.stamps)

    def __len__(self) -> int:
        return self.n_touches

    @property
    def act_touch(self) -> np.ndarray:
        return self.contact_touch[self.act_contact]

    @property
    def act_part(self) -> np.ndarray:
        return self.contact_part[self.act_contact]

    def derived(self, key: tuple, compute, owners: tuple = ()):
        """``compute()`` once per ``key`` (and identity of every object in ``owners``, e.g. the skin).

        A touch set is never modified once built, so what is derived from it
        stays right; results are read-only arrays or tuples of them, shared by
        every caller.
        """
        hit = self._derived.get(key)
        if hit is not None and len(hit[0]) == len(owners) and all(a is b for a, b in zip(hit[0], owners)):
            return hit[1]
        value = compute()
        self._derived[key] = (owners, value)
        return value

    @property
    def fingertip_of_touch(self) -> np.ndarray:
        """(N,) int: the fingertip (index into ``fingertips``) of each touch, -1 for a self-touch."""
        return self.touch_fingertip if self.touch_fingertip is not None else np.full(self.n_touches, -1)

    def with_fingertip(self, name: str) -> "TouchSet":
        """These touches as fingertip touches of ``name`` (every one)."""
        return replace(self, fingertips=(name,), touch_fingertip=np.zeros(self.n_touches, int))

    def part_index(self, name: str) -> int:
        try:
            return self.part_names.index(name)
        except ValueError:
            raise KeyError(f"skin part '{name}' not in this touch set ({', '.join(self.part_names)})") from None

    # ------------------------------------------------------------------ building
    @classmethod
    def empty(cls, part_names: Sequence[str], joint_names: Sequence[str]) -> "TouchSet":
        return cls(tuple(part_names), tuple(joint_names), np.zeros(0), [], np.zeros((0, len(joint_names))),
                   np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)),
                   np.zeros(0, int), np.zeros(0, int), np.zeros(0))

    def subset(self, touches: np.ndarray) -> "TouchSet":
        """The given touch rows (indices or boolean mask), in that order."""
        touches = np.asarray(touches)
        if touches.dtype == bool:
            touches = np.flatnonzero(touches)
        new_row = np.full(self.n_touches, -1)
        new_row[touches] = np.arange(len(touches))
        # contacts ordered by their new touch row, keeping their order within a touch
        keep_c = np.flatnonzero(new_row[self.contact_touch] >= 0)
        keep_c = keep_c[np.argsort(new_row[self.contact_touch[keep_c]], kind="stable")]
        new_c = np.full(len(self.contact_touch), -1)
        new_c[keep_c] = np.arange(len(keep_c))
        keep_a = np.flatnonzero(new_c[self.act_contact] >= 0)
        keep_a = keep_a[np.argsort(new_c[self.act_contact[keep_a]], kind="stable")]
        return TouchSet(
            self.part_names, self.joint_names, self.stamps[touches], [self.keys[i] for i in touches],
            self.joints[touches], new_row[self.contact_touch[keep_c]], self.contact_part[keep_c],
            self.contact_id[keep_c], self.contact_cop[keep_c], new_c[self.act_contact[keep_a]],
            self.act_slot[keep_a], self.act_pressure[keep_a],
            {k: np.asarray(v)[touches] for k, v in self.labels.items()}, self.fingertips,
            None if self.touch_fingertip is None else self.touch_fingertip[touches])

    @staticmethod
    def concatenate(sets: Sequence["TouchSet"]) -> "TouchSet":
        """Touches of several sets (same joint names); part names are merged."""
        sets = [s for s in sets]
        if not sets:
            raise ValueError("nothing to concatenate")
        joint_names = sets[0].joint_names
        parts: list = []
        for s in sets:
            if s.joint_names != joint_names:
                raise ValueError("touch sets with different joint names cannot be concatenated")
            parts += [p for p in s.part_names if p not in parts]
        out = []
        n_off = c_off = 0
        for s in sets:
            remap = np.array([parts.index(p) for p in s.part_names], dtype=int)
            out.append((s, n_off, c_off, remap))
            n_off += s.n_touches
            c_off += len(s.contact_touch)
        label_keys = set.intersection(*(set(s.labels) for s in sets)) if sets else set()
        fingertips = tuple(dict.fromkeys(f for s in sets for f in s.fingertips))
        touch_fingertip = None
        if fingertips:
            touch_fingertip = np.concatenate([
                np.where(s.fingertip_of_touch >= 0,
                         np.array([fingertips.index(f) for f in s.fingertips] + [-1], int)[s.fingertip_of_touch], -1)
                for s in sets]).astype(int)
        return TouchSet(
            tuple(parts), joint_names,
            np.concatenate([s.stamps for s in sets]),
            [k for s in sets for k in s.keys],
            np.concatenate([s.joints for s in sets]),
            np.concatenate([s.contact_touch + n for s, n, _, _ in out]).astype(int),
            np.concatenate([r[s.contact_part] if len(s.contact_part) else s.contact_part for s, _, _, r in out]).astype(int),
            np.concatenate([s.contact_id for s in sets]).astype(int),
            np.concatenate([s.contact_cop for s in sets]),
            np.concatenate([s.act_contact + c for s, _, c, _ in out]).astype(int),
            np.concatenate([s.act_slot for s in sets]).astype(int),
            np.concatenate([s.act_pressure for s in sets]),
            {k: np.concatenate([np.asarray(s.labels[k]) for s in sets]) for k in label_keys},
            fingertips, touch_fingertip)

    def parts_of_touch(self) -> np.ndarray:
        """(N, P) bool: which parts have at least one activation in each touch."""
        out = np.zeros((self.n_touches, len(self.part_names)), dtype=bool)
        out[self.contact_touch, self.contact_part] = True
        return out
