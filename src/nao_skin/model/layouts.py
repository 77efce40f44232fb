"""The project's own default taxel layouts for the four Nao skin parts.

Triangle modules (10 pressure taxels on a triangular lattice, ~6 mm pitch,
30 mm side; slots 6 and 10 are the thermal pads) tiled on simple surfaces
of the right size: rounded hands (cylinders along the forearm axis, which is
-y of the DH hand frame), a gently curved chest, a spherical cap on the head.
Real layouts come from the user's skinManager files; these make simulation
and the demo run without any external file.

Regenerate with ``nao-skin layouts config/layouts`` (deterministic).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nao_skin.model.taxel_file import SLOTS_PER_TRIANGLE, THERMAL_SLOTS, write_taxel_file

TRIANGLE_SIDE = 0.030        # module side (m)
GRID_SIDE = 0.0315           # tiling pitch: modules sit with a small gap
LATTICE_SHRINK = 0.6         # taxel lattice pitch = shrink * side / 3 = 6 mm
PRESSURE_SLOTS = [k for k in range(SLOTS_PER_TRIANGLE) if k not in THERMAL_SLOTS]


def _tile(n: int, centre_uv=(0.0, 0.0), keep=None):
    """n equilateral triangles (corners in (u, v) metres) nearest the centre of a grid."""
    h = GRID_SIDE * np.sqrt(3) / 2
    tris = []
    for r in range(-8, 9):
        for c in range(-12, 13):
            u0 = c * GRID_SIDE / 2
            v0 = r * h
            up = (r + c) % 2 == 0
            if up:
                corners = np.array([[u0 - GRID_SIDE / 2, v0], [u0 + GRID_SIDE / 2, v0], [u0, v0 + h]])
            else:
                corners = np.array([[u0 - GRID_SIDE / 2, v0 + h], [u0 + GRID_SIDE / 2, v0 + h], [u0, v0]])
            tris.append(corners)
    tris = np.array(tris)
    centroids = tris.mean(axis=1)
    if keep is not None:
        mask = np.array([keep(cen) for cen in centroids])
        tris, centroids = tris[mask], centroids[mask]
    d = np.linalg.norm(centroids - np.asarray(centre_uv), axis=1)
    order = np.lexsort((centroids[:, 1], centroids[:, 0], np.round(d, 9)))[:n]
    return tris[order]


def _module(corners3d: np.ndarray, outward: np.ndarray):
    """10 taxel positions and the normal of a flat module spanning three mapped corners."""
    centre = corners3d.mean(axis=0)
    normal = np.cross(corners3d[1] - corners3d[0], corners3d[2] - corners3d[0])
    normal /= np.linalg.norm(normal)
    if normal @ outward < 0:
        normal = -normal
    # corners rescaled to the module size around the centre, kept in the module plane
    scale = TRIANGLE_SIDE / GRID_SIDE
    a, b, c = centre + scale * (corners3d - centre)
    points = []
    for i in range(4):
        for j in range(4 - i):
            k = 3 - i - j
            p = (i * a + j * b + k * c) / 3.0
            points.append(centre + LATTICE_SHRINK * (p - centre))
    return np.array(points), normal


def _layout(triangles_uv, surface, patch_split):
    """Place tiles on a surface; triangles of patch 0 get ids 0.., patch 1 ids 16.."""
    positions = np.zeros((384, 3))
    normals = np.zeros((384, 3))
    centroids = triangles_uv.mean(axis=1)
    order = np.lexsort((centroids[:, 1], centroids[:, 0]))
    first = order[:patch_split]
    second = order[patch_split:]
    ids = {int(t): i for i, t in enumerate(first)}
    ids.update({int(t): 16 + i for i, t in enumerate(second)})
    for t, corners in enumerate(triangles_uv):
        pts3d, outward = zip(*(surface(uv) for uv in corners))
        taxels, normal = _module(np.array(pts3d), np.mean(outward, axis=0))
        tri = ids[t]
        for k, p in zip(PRESSURE_SLOTS, taxels):
            positions[tri * SLOTS_PER_TRIANGLE + k] = p
            normals[tri * SLOTS_PER_TRIANGLE + k] = normal
    return positions, normals


def hand_layout():
    """Cylinder (r = 32 mm) around the forearm axis (-y of the hand frame), 35..125 mm from the elbow."""
    radius = 0.032

    def surface(uv):
        along, arc = uv
        phi = arc / radius
        return np.array([radius * np.cos(phi), -along, radius * np.sin(phi)]), np.array([np.cos(phi), 0.0, np.sin(phi)])

    tris = _tile(24, centre_uv=(0.08, 0.0),
                 keep=lambda c: 0.045 <= c[0] <= 0.115 and abs(c[1]) < np.pi * radius - 0.012)
    return _layout(tris, surface, 12)


def torso_layout():
    """Chest: vertical cylinder of radius 0.2 m whose front is at x = 55 mm; z in about -10..75 mm."""
    radius, front = 0.2, 0.055

    def surface(uv):
        z, arc = uv
        phi = arc / radius
        return (np.array([front - radius + radius * np.cos(phi), radius * np.sin(phi), z]),
                np.array([np.cos(phi), np.sin(phi), 0.0]))

    tris = _tile(25, centre_uv=(0.03, 0.0))
    return _layout(tris, surface, 13)


def head_layout():
    """Spherical cap (r = 62 mm) on the front-top of the head; head frame: x up, z forward at rest."""
    radius = 0.062
    centre = np.array([0.055, 0.0, 0.0])
    pole = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)      # between up and forward
    e1 = np.array([0.0, 1.0, 0.0])                      # sideways
    e2 = np.cross(pole, e1)

    def surface(uv):
        u, v = uv
        rho = np.hypot(u, v) / radius                    # azimuthal equidistant map
        direction = pole if rho < 1e-12 else (np.cos(rho) * pole + np.sin(rho) * (u * e1 + v * e2) / np.hypot(u, v))
        return centre + radius * direction, direction

    tris = _tile(24, centre_uv=(0.0, 0.0))
    return _layout(tris, surface, 12)


LAYOUTS = {"r_hand": hand_layout, "l_hand": hand_layout, "torso": torso_layout, "head": head_layout}


def write_default_layouts(directory: str | Path) -> list:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name, make in LAYOUTS.items():
        pos, nor = make()
        present = np.any(pos != 0, axis=1)
        path = directory / f"{name}.txt"
        write_taxel_file(path, pos, nor, present, name)
        written.append(path)
    return written
