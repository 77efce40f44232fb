"""Residuals and analytic sparse Jacobians of paired skin points, vectorised over touches.

The unknowns are the 6-vector corrections ``[t, rotvec]`` of skin frames
(mounts, patches, triangles). A residual row is ``sum_k w_k x_k`` over its
terms, ``x_k`` the calibrated base-frame position of one taxel, so a COP pair
and a taxel pair are the same thing to the solver (see
:class:`nao_skin.calibration.pairing.Pairing`). In a normal row (``KIND_NORMAL``) ``x_k``
is the taxel's base-frame normal instead: rotated like a point, never moved.
Each term depends on exactly one chain of frames (its part's mount, its
patch, its triangle), so the Jacobian is sparse with at most 18 non-zeros per
term and coordinate; it is assembled from
closed-form 3x6 blocks, vectorised over all terms.

For a correction ``exp(d) = (R(phi), t)`` between a frame ``G`` (everything
above it, including the robot's forward kinematics) and a point ``y``
(everything below it) the position is ``x = G (R(phi) y + t)`` and

    dx/dt   = R_G
    dx/dphi = -R_G R(phi) [y]x J_r(phi)

with ``J_r`` the right Jacobian of SO(3) (:func:`se3.right_jacobian`); exact also for the large mount
rotations (about 160 degrees) real hands start from.

Kinematic corrections (joint-angle offsets, link lengths: the layout's ``kinematic_names``) move the
chain ends themselves: their few columns are forward differences of the residuals, each one batched
forward kinematics over the touches.

A fingertip row (:mod:`~nao_skin.calibration.fingertip`) has the fingertip's contact sphere as its side B:
``r n - T(q) c``, affine in the sphere's centre ``c`` and radius ``r`` (its four columns: ``-R(q)`` and ``n``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.linalg.blas
import scipy.sparse

from nao_skin import se3
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import KIND_NORMAL
from nao_skin.model.skin import SkinCalibration, SkinModel

DENSE_LIMIT = 2_000_000     # Jacobian entries above which it is kept sparse
KINEMATIC_STEP = 1e-6       # rad or m: forward-difference step of a kinematic column (~1e-7 m at the hand)


def gram(j, w=None) -> np.ndarray:
    """Dense ``J^T diag(w) J`` for a dense or sparse Jacobian (``w >= 0``).

    Dense: a symmetric rank-k update of ``sqrt(w) J`` (BLAS ``syrk``) computes one triangle, half the
    products of ``J^T (w J)``; the gram is the solver's largest cost on the real recording.
    """
    if scipy.sparse.issparse(j):
        h = j.T @ (j if w is None else j.multiply(w[:, None]).tocsr())
        return h.toarray() if scipy.sparse.issparse(h) else h
    a = np.asarray(j, dtype=float) if w is None else j * np.sqrt(w)[:, None]
    if a.shape[0] == 0 or a.shape[1] == 0:
        return np.zeros((a.shape[1], a.shape[1]))
    # a.T is a Fortran-ordered view of the C-ordered rows: syrk reads it in place
    h = scipy.linalg.blas.dsyrk(1.0, a.T, trans=0, lower=0)
    lower = np.tril_indices(len(h), -1)
    h[lower] = h.T[lower]
    return h


def jt_dot(j, v: np.ndarray) -> np.ndarray:
    return np.asarray(j.T @ v).ravel()


class ResidualModel:
    """Residuals ``r(x)`` and Jacobians for one pairing, vectorised over its terms.

    ``chain_poses(part)``: the (N, 4, 4) chain-end pose of that part in every
    touch (e.g. :func:`~nao_skin.calibration.pairing.chain_end_poses`): joint
    angles do not change while corrections are estimated, so it is taken once.
    """

    def __init__(self, skin: SkinModel, chain_poses, pairing, part_names: tuple,
                 layout: ParameterLayout, base: SkinCalibration, variable_parts=None,
                 fabric: float = 0.0, kinematic_poses=None, fingertip_names: tuple = ()):
        self.skin = skin
        # touching skins meet at their fabric surfaces, not at the taxel centres: each taxel
        # is lifted along its normal (fixed in its triangle frame) by the fabric thickness,
        # which is read from x[fabric_col] (an unknown like the corrections)
        self.fabric = float(fabric)
        self.layout = layout
        self.base = base
        self.n_rows = len(pairing.row_touch)
        self.term_row = pairing.term_row
        self.term_weight = pairing.term_weight
        self.groups = []   # one per part: (term indices, part, FK per term, slot arrays)
        # with kinematic unknowns: ``kinematic_poses(calib)`` is the ``chain_poses`` of the robot that
        # calib's kinematic corrections describe; the chain ends are taken again when they change
        self._kinematic_poses = kinematic_poses
        self._kinematic_key = None
        # parts whose corrections are constant while this model lives: positions computed once
        self.variable_parts = None if variable_parts is None else set(variable_parts)
        self._constant = np.zeros((self.n_rows, 3))
        self._constant_done = False
        term_touch = pairing.row_touch[pairing.term_row]
        for pidx in np.unique(pairing.term_part):
            name = part_names[pidx]
            part = skin.parts[name]
            sel = np.flatnonzero(pairing.term_part == pidx)
            slots = pairing.term_slot[sel]
            tri = part.slot_triangle[slots]
            if np.any(tri < 0):
                bad = slots[tri < 0][0]
                raise ValueError(f"part '{name}': slot {bad} has no taxel in the layout")
            fk = chain_poses(name)[term_touch[sel]]
            self.groups.append((sel, name, part, fk, slots, tri, part.triangle_patch[tri]))
        self._term_touch = term_touch
        self._tips = _fingertip_sides(pairing, chain_poses, fingertip_names, self.n_rows)
        self._row_touch = pairing.row_touch
        # terms of normal rows carry a direction (rotated, never translated, no fabric)
        self.term_is_dir = pairing.row_kind[pairing.term_row] == KIND_NORMAL
        self.has_dirs = bool(np.any(self.term_is_dir))
        self._dir_terms = [np.flatnonzero(self.term_is_dir[group[0]]) for group in self.groups]
        # the pairing is fixed while the model lives, so are which terms share a (row, block), their
        # summed weights, where each block's entries go in the Jacobian and, until the kinematics
        # change, the chain-end rotation of each (row, block) (keys ending in "A"): computed once
        self._per_pairing: dict = {}
        self._last_jacobian = None   # (key, J): the hold check and the first solve step share it
        # point-to-plane rows count only along their normal: residual and Jacobian rows are projected
        # by n n^T (fixed while the pairing is, as in ICP), so the robust loss sees |n . r|
        normal = pairing.row_normal
        self._projected = (np.zeros(0, int) if normal is None
                           else np.flatnonzero(np.all(np.isfinite(normal), axis=1)))
        self._projection_normal = normal[self._projected] if len(self._projected) else None
        # what a row is expected to be at the true skin (the press model's): the residual is the row minus it
        self._offset = pairing.row_offset

    def _row_blocks(self, key: tuple, term_row: np.ndarray, block_rows: np.ndarray):
        """``(first, inverse, n)`` of the unique (row, block) combinations of one group's terms."""
        hit = self._per_pairing.get(key)
        if hit is None:
            code = term_row * (int(block_rows.max()) + 1 if len(block_rows) else 1) + block_rows
            uniq, first, inverse = np.unique(code, return_index=True, return_inverse=True)
            hit = self._per_pairing[key] = (first, inverse, len(uniq))
        return hit

    def _use_kinematics(self, calib: SkinCalibration) -> None:
        """Chain ends of the robot ``calib``'s kinematic corrections describe (when they are unknowns)."""
        if self._kinematic_poses is None:
            return
        key = tuple(sorted(calib.kinematics.items()))
        if key == self._kinematic_key:
            return
        chain_poses = self._kinematic_poses(calib)
        self.groups = [(sel, name, part, chain_poses(name)[self._term_touch[sel]], *rest)
                       for sel, name, part, _, *rest in self.groups]
        self._tips = [(name, rows, chain_poses(name)[self._row_touch[rows]], *rest)
                      for name, rows, _, *rest in self._tips]
        self._kinematic_key = key
        self._constant = np.zeros((self.n_rows, 3))
        self._constant_done = False
        self._per_pairing = {k: v for k, v in self._per_pairing.items() if k[-1] != "A"}

    def _is_variable(self, name: str) -> bool:
        return self.variable_parts is None or name in self.variable_parts

    # ------------------------------------------------------------------ evaluation
    def _group_positions(self, g: int, calib: SkinCalibration) -> np.ndarray:
        """(3, terms) base-frame position of each term's taxel of group ``g`` (its normal, for terms of
        normal rows), coordinate first."""
        sel, name, part, fk, slots, tri, _ = self.groups[g]
        _, _, tri_pose = part.frame_poses(calib.parts[name])
        # chain-end position of every slot of the part once (<= 384), then gathered per term
        frames = tri_pose[part.slot_triangle]
        local = se3.transform_points(frames, part.taxel_local + self.fabric * part.normal_local)
        if self.has_dirs:
            local = local[slots]
            dirs = self._dir_terms[g]
            local[dirs] = se3.rotate_vectors(frames, part.normal_local)[slots[dirs]]
            local = np.ascontiguousarray(local.T)
        else:
            local = np.ascontiguousarray(local.T)[:, slots]
        rot, trans = self._chain_coordinates(g)
        return se3.transform_coordinates(rot, local, trans)

    def _chain_coordinates(self, g: int) -> tuple:
        """The chain-end rotation and translation of each term of group ``g``, coordinate first
        (:func:`se3.split_coordinates`); the translation is zero for directions. Fixed with the chain ends."""
        key = (g, "chain coordinates", "A")
        hit = self._per_pairing.get(key)
        if hit is None:
            rot, trans = se3.split_coordinates(self.groups[g][3])
            trans[:, self.term_is_dir[self.groups[g][0]]] = 0.0
            hit = self._per_pairing[key] = (rot, trans)
        return hit

    def positions(self, calib: SkinCalibration) -> np.ndarray:
        """(K, 3) base-frame positions of every term's taxel."""
        self._use_kinematics(calib)
        out = np.empty((len(self.term_row), 3))
        for g, group in enumerate(self.groups):
            out[group[0]] = self._group_positions(g, calib).T
        return out

    def residuals(self, calib: SkinCalibration, fabric: float | None = None) -> np.ndarray:
        """(M, 3) residual vectors, one per pairing row."""
        self._use_kinematics(calib)
        if fabric is not None and fabric != self.fabric:
            self.fabric = float(fabric)
            self._constant = np.zeros((self.n_rows, 3))
            self._constant_done = False
        if not self._constant_done:
            for g, group in enumerate(self.groups):
                if not self._is_variable(group[1]):
                    sel = group[0]
                    x = self._group_positions(g, calib) * self.term_weight[sel]
                    for d in range(3):
                        self._constant[:, d] += np.bincount(self.term_row[sel], weights=x[d], minlength=self.n_rows)
            self._constant_done = True
        out = self._constant.copy()
        for g, group in enumerate(self.groups):
            if self._is_variable(group[1]):
                sel = group[0]
                x = self._group_positions(g, calib) * self.term_weight[sel]
                for d in range(3):
                    out[:, d] += np.bincount(self.term_row[sel], weights=x[d], minlength=self.n_rows)
        if self._offset is not None:
            out -= self._offset
        for name, rows, poses, direction, weight in self._tips:
            centre, radius = calib.fingertip_sphere(self.skin.robot, name)
            out[rows] += weight[:, None] * (radius * direction - se3.transform_points(poses, centre))
        return self._project(out)

    def _project(self, rows: np.ndarray) -> np.ndarray:
        """``rows`` ((M, 3) residuals or (M, 3, C) Jacobian rows) with the point-to-plane rows projected."""
        if self._projection_normal is None:
            return rows
        n = self._projection_normal
        sub = rows[self._projected]
        along = np.einsum("mi,mi...->m...", n, sub)
        rows[self._projected] = n.reshape(n.shape + (1,) * (sub.ndim - 2)) * along[:, None]
        return rows

    def jacobian(self, calib: SkinCalibration, free_levels: dict, cols: np.ndarray | None = None) -> np.ndarray:
        """Dense (3M, len(cols)) Jacobian of the stacked residuals w.r.t. the layout columns ``cols``.

        ``free_levels`` maps part name -> set of levels whose blocks get columns
        (other blocks are constant and produce no entries). Built from the
        per-(row, block) 3x6 blocks written into a dense array: the unknowns of
        one stage are few (at most a few hundred), so dense normal equations
        are fastest. The last Jacobian is kept: the check for unexcited
        directions and the first solver step ask for the same one.
        """
        cols = np.arange(self.layout.size) if cols is None else np.asarray(cols)
        key = (self.layout.to_vector(calib, self.fabric).tobytes(), cols.tobytes(),
               tuple(sorted((k, tuple(sorted(v))) for k, v in free_levels.items())),
               3 * self.n_rows * len(cols) > DENSE_LIMIT)
        if self._last_jacobian is not None and self._last_jacobian[0] == key:
            return self._last_jacobian[1]
        jac = self._project_jacobian(self._jacobian(calib, free_levels, cols))
        kinematic = np.flatnonzero(np.isin(cols, list(self.layout.kinematic_cols.values())))
        if len(kinematic):
            jac = self._with_kinematic_columns(jac, calib, cols, kinematic)
        if self._tips and self.layout.fingertip_cols:
            jac = self._with_fingertip_columns(jac, cols)
        self._last_jacobian = (key, jac)
        return jac

    def _project_jacobian(self, jac):
        """``jac`` (dense or sparse) with the rows of point-to-plane residuals projected on their normals."""
        if self._projection_normal is None:
            return jac
        if not scipy.sparse.issparse(jac):
            self._project(jac.reshape(self.n_rows, 3, -1))
            return jac
        # block-diagonal n n^T on the projected rows, identity elsewhere
        blocks = np.broadcast_to(np.eye(3), (self.n_rows, 3, 3)).copy()
        n = self._projection_normal
        blocks[self._projected] = n[:, :, None] * n[:, None, :]
        first = 3 * np.arange(self.n_rows)[:, None, None]
        rows = np.broadcast_to(first + np.arange(3)[None, :, None], blocks.shape).ravel()
        cols = np.broadcast_to(first + np.arange(3)[None, None, :], blocks.shape).ravel()
        proj = scipy.sparse.csr_matrix((blocks.ravel(), (rows, cols)), shape=(3 * self.n_rows, 3 * self.n_rows))
        return (proj @ jac).tocsr()

    def _with_kinematic_columns(self, jac, calib: SkinCalibration, cols: np.ndarray, kinematic: np.ndarray):
        """``jac`` with its kinematic columns (positions ``kinematic`` in ``cols``) by forward differences."""
        base = self.residuals(calib).ravel()
        names = self.layout.kinematic_names
        block = np.empty((len(base), len(kinematic)))
        for k, j in enumerate(kinematic):     # a handful of unknowns, each one batched FK and residual
            moved = replace(calib, kinematics=dict(calib.kinematics))
            name = names[cols[j] - self.layout.fabric_col - 1]
            moved.kinematics[name] = moved.kinematics.get(name, 0.0) + KINEMATIC_STEP
            block[:, k] = (self.residuals(moved).ravel() - base) / KINEMATIC_STEP
        self._use_kinematics(calib)
        if scipy.sparse.issparse(jac):
            rows, which = np.nonzero(block)
            extra = scipy.sparse.csr_matrix((block[rows, which], (rows, kinematic[which])), shape=jac.shape)
            return (jac + extra).tocsr()
        jac = jac.copy()
        jac[:, kinematic] = block
        return jac

    def _with_fingertip_columns(self, jac, cols: np.ndarray):
        """``jac`` with the columns of the fingertips' spheres (centre: ``-R(q)`` of each row's touch, radius: the
        row's direction), where ``cols`` asks for them; fingertip rows are never projected."""
        col_of = {int(c): j for j, c in enumerate(cols)}
        rows_all, cols_all, vals_all = [], [], []
        for name, rows, poses, direction, weight in self._tips:
            first = self.layout.fingertip_cols.get(name)
            if first is None:
                continue
            coords = 3 * rows[:, None] + np.arange(3)[None, :]           # (m, 3) Jacobian rows
            for k in range(3):
                j = col_of.get(first + k)
                if j is not None:
                    rows_all.append(coords.ravel())
                    cols_all.append(np.full(coords.size, j))
                    vals_all.append((-weight[:, None] * poses[:, :3, k]).ravel())
            j = col_of.get(first + 3)
            if j is not None:
                rows_all.append(coords.ravel())
                cols_all.append(np.full(coords.size, j))
                vals_all.append((weight[:, None] * direction).ravel())
        if not rows_all:
            return jac
        r, c, v = (np.concatenate(a) for a in (rows_all, cols_all, vals_all))
        if scipy.sparse.issparse(jac):
            return (jac + scipy.sparse.csr_matrix((v, (r, c)), shape=jac.shape)).tocsr()
        jac = jac.copy()
        jac[r, c] = v
        return jac

    def _jacobian(self, calib: SkinCalibration, free_levels: dict, cols: np.ndarray):
        self._use_kinematics(calib)
        col_of = np.full(self.layout.size, -1)
        col_of[cols] = np.arange(len(cols))
        n_cols = len(cols)
        shape = (3 * self.n_rows, n_cols)
        # many unknowns at once (a joint stage): keep the block sparsity
        dense = shape[0] * shape[1] <= DENSE_LIMIT
        # each (row, column) entry is written once: a row's terms are summed per block below,
        # blocks of different levels or parts own different columns, the fabric column is summed
        out = np.zeros(shape) if dense else None
        rows_all, cols_all, vals_all = [], [], []   # the sparse Jacobian's entries
        fabric_j = col_of[self.layout.fabric_col] if self.layout.fabric_col < len(col_of) else -1
        # the fabric column sums over both sides of a row: accumulated apart from the blocks
        fabric_column = np.zeros(3 * self.n_rows) if fabric_j >= 0 else None
        for g, (sel, name, part, fk, slots, tri, patch) in enumerate(self.groups):
            levels = free_levels.get(name, ())
            if not levels and fabric_j < 0:
                continue
            corr = calib.parts[name]
            # one batched Rodrigues for the mount, the patches and the triangles
            rot = se3.rotvec_to_matrix(np.concatenate([corr.mount[None], corr.patches, corr.triangles])[:, 3:])
            r_m, r_p, r_t = rot[0], rot[1:1 + len(corr.patches)], rot[1 + len(corr.patches):]
            term_row = self.term_row[sel]
            wv = self.term_weight[sel]
            # rotation of each patch / triangle frame relative to the corrected mount frame
            r_patch = r_m @ part.patch_nominal[:, :3, :3]                                   # C of a patch
            r_tri = (r_patch @ r_p)[part.triangle_patch] @ part.triangle_nominal[:, :3, :3]  # C of a triangle
            if fabric_j >= 0:   # d r / d fabric: the weighted sum of the rows' taxel normals
                # terms of one row on one triangle share its rotation: their local normals are summed once
                first, _, wn = self._block_sums(g, "triangle", tri, normals=True)
                a = self._chain_rotation(g, "triangle", fk, first, part)
                nrm = np.einsum("gij,gj->gi", a, np.einsum("gij,gj->gi", (r_tri @ r_t)[tri[first]], wn))
                fabric_column += np.bincount((3 * term_row[first][:, None] + np.arange(3)[None, :]).ravel(),
                                             weights=nrm.ravel(), minlength=3 * self.n_rows)
            if not levels:
                continue
            # every slot's point below each correction, computed once per slot (a part has <= 384)
            # and gathered per term: y_T = q ; y_P = T_n exp(dT) q ; y_M = P_n exp(dP) y_P
            q_pt = part.taxel_local + self.fabric * part.normal_local
            q_dir = part.normal_local
            below = {"triangle": (q_pt, q_dir)}
            if "mount" in levels or "patch" in levels:
                st = part.slot_triangle
                t_rot = part.triangle_nominal[st, :3, :3] @ r_t[st]
                t_off = (np.einsum("sij,sj->si", part.triangle_nominal[st, :3, :3], corr.triangles[st, :3])
                         + part.triangle_nominal[st, :3, 3])
                below["patch"] = (np.einsum("sij,sj->si", t_rot, q_pt) + t_off, np.einsum("sij,sj->si", t_rot, q_dir))
                if "mount" in levels:
                    sp = part.triangle_patch[st]
                    p_rot = part.patch_nominal[sp, :3, :3] @ r_p[sp]
                    p_off = (np.einsum("sij,sj->si", part.patch_nominal[sp, :3, :3], corr.patches[sp, :3])
                             + part.patch_nominal[sp, :3, 3])
                    y_pt, y_dir = below["patch"]
                    below["mount"] = (np.einsum("sij,sj->si", p_rot, y_pt) + p_off, np.einsum("sij,sj->si", p_rot, y_dir))
            for level in ("mount", "patch", "triangle"):
                if level not in levels:
                    continue
                block_rows = {"mount": np.zeros(len(sel), int), "patch": patch, "triangle": tri}[level]
                take, rows, cols_, flat = self._block_places(g, level, block_rows, cols, col_of)
                if len(rows) == 0:
                    continue
                y_pt, y_dir = below[level]
                y = y_pt[slots]
                dirs = self._dir_terms[g]
                y[dirs] = y_dir[slots[dirs]]
                # Terms of one residual row under the same block share everything but y, and
                # the position is affine in y: sum them first (sum w y, sum w), one block each.
                first, inverse, wsum = self._block_sums(g, level, block_rows)
                wy = np.stack([np.bincount(inverse, weights=wv * y[:, d], minlength=len(first)) for d in range(3)], 1)
                # R_G = A C_b: A (the touch's chain end and nominal mount) is fixed while the model
                # lives, C_b (above the block, below the mount) is per block. With R_c the
                # correction, J_r its right Jacobian and D_b = C_b R_c:
                #   A C_b R_c [wy]x J_r = [A D_b wy]x A D_b J_r
                a = self._chain_rotation(g, level, fk, first, part)
                if level == "mount":
                    c_b, r_c, phi = np.eye(3)[None], r_m[None], corr.mount[None, 3:]
                    blk = np.zeros(len(first), int)
                elif level == "patch":
                    c_b, r_c, phi, blk = r_patch, r_p, corr.patches[:, 3:], patch[first]
                else:
                    c_b, r_c, phi, blk = r_tri, r_t, corr.triangles[:, 3:], tri[first]
                d_b = c_b @ r_c
                n_b = d_b @ se3.right_jacobian(phi)
                a_v = np.einsum("gij,gj->gi", a, np.einsum("gij,gj->gi", d_b[blk], wy))
                d_phi = -(se3.skew(a_v) @ (a @ n_b[blk]))
                d_t = (a @ c_b[blk]) * wsum[:, None, None]
                block = np.concatenate([d_t, d_phi], axis=2).ravel()   # (G, 3, 6) blocks
                vals = block if take is None else block[take]
                if dense:
                    out.ravel()[flat] = vals
                else:
                    rows_all.append(rows)
                    cols_all.append(cols_)
                    vals_all.append(vals)
        if fabric_column is not None:
            nz = np.flatnonzero(fabric_column)
            if dense:
                out[nz, fabric_j] = fabric_column[nz]
            else:
                rows_all.append(nz)
                cols_all.append(np.full(len(nz), fabric_j))
                vals_all.append(fabric_column[nz])
        if dense:
            return out
        if not rows_all:
            return np.zeros(shape)
        return scipy.sparse.csr_matrix((np.concatenate(vals_all), (np.concatenate(rows_all), np.concatenate(cols_all))),
                                       shape=shape)

    def _block_sums(self, g: int, level: str, block_rows: np.ndarray, normals: bool = False):
        """``(first, inverse, sums)`` of the (row, block) combinations of group ``g``'s terms at one level:
        ``sums`` the terms' weights summed per combination (directions excluded), or with ``normals``
        their weighted local taxel normals. Fixed while the pairing is: computed once."""
        key = (g, level, "normals" if normals else "sums")
        hit = self._per_pairing.get(key)
        if hit is None:
            sel, _, part, _, slots, _, _ = self.groups[g]
            first, inverse, n = self._row_blocks((g, level), self.term_row[sel], block_rows)
            # directions neither translate nor depend on the fabric
            wv_t = np.where(self.term_is_dir[sel], 0.0, self.term_weight[sel])
            if normals:
                sums = np.stack([np.bincount(inverse, weights=wv_t * part.normal_local[slots, d], minlength=n)
                                 for d in range(3)], 1)
            else:
                sums = np.bincount(inverse, weights=wv_t, minlength=n)
            hit = self._per_pairing[key] = (first, inverse, sums)
        return hit

    def _block_places(self, g: int, level: str, block_rows: np.ndarray, cols: np.ndarray, col_of: np.ndarray):
        """Where the entries of group ``g``'s (G, 3, 6) blocks at one level go in a Jacobian of the
        columns ``cols`` (``col_of``: the Jacobian column of each layout column, -1 if not free):
        ``(take, rows, cols, flat)``, ``take`` the flattened blocks' entries in a free column (None:
        all), ``flat`` their index in a dense Jacobian. Fixed while the pairing and the free columns
        are: computed once."""
        key = (g, level, "places", cols.tobytes())
        hit = self._per_pairing.get(key)
        if hit is None:
            sel, name = self.groups[g][:2]
            term_row = self.term_row[sel]
            first, _, _ = self._row_blocks((g, level), term_row, block_rows)
            cc = col_of[self.layout.block_columns(name, level, block_rows[first])[:, None] + np.arange(6)[None, :]]
            shape = (len(first), 3, 6)
            keep = np.broadcast_to((cc >= 0)[:, None, :], shape)
            rows = np.broadcast_to((3 * term_row[first])[:, None, None] + np.arange(3)[None, :, None], shape)[keep]
            cols_ = np.broadcast_to(cc[:, None, :], shape)[keep]
            take = None if keep.all() else np.flatnonzero(keep)
            hit = self._per_pairing[key] = (take, rows, cols_, rows * len(cols) + cols_)
        return hit

    def _chain_rotation(self, g: int, level: str, fk: np.ndarray, first: np.ndarray, part) -> np.ndarray:
        """Rotation of the touch's chain end times the nominal mount, one per (row, block) of a level."""
        key = (g, level, "A")
        hit = self._per_pairing.get(key)
        if hit is None:
            hit = self._per_pairing[key] = fk[first, :3, :3] @ part.mount_nominal[:3, :3]
        return hit


def _fingertip_sides(pairing, chain_poses, fingertip_names: tuple, n_rows: int) -> list:
    """The fingertip side of the fingertip rows: per fingertip, its rows, their touches' chain-end poses, the rows'
    directions and the weight the row's skin side carries (its terms' weights sum to it: 1, or the touch's
    weight), which the fingertip's side carries too."""
    if pairing.row_fingertip is None:
        return []
    side_a = np.bincount(pairing.term_row, weights=pairing.term_weight, minlength=n_rows)
    out = []
    for f in np.unique(pairing.row_fingertip[pairing.row_fingertip >= 0]):
        rows = np.flatnonzero(pairing.row_fingertip == f)
        name = fingertip_names[f]
        out.append((name, rows, chain_poses(name)[pairing.row_touch[rows]], pairing.row_direction[rows], side_a[rows]))
    return out


def condition_number(model: ResidualModel, calib: SkinCalibration, free_levels: dict, cols: np.ndarray) -> float:
    """Condition number of the Jacobi-scaled normal equations (how well the data pins the unknowns)."""
    if len(cols) == 0:
        return float("nan")
    h = gram(model.jacobian(calib, free_levels, cols))
    s = np.sqrt(np.maximum(np.diag(h), 1e-300))
    ev = np.linalg.eigvalsh(h / np.outer(s, s))
    return float(ev[-1] / max(ev[0], 1e-300))
