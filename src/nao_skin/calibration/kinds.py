"""The names the options table shares with the engine: the levels a stage frees, the kinds of residual
rows and how point-to-plane rows are weighted.

Plain constants without numpy: the options table is read for ``nao-skin calibrate --help`` and every
check of an option before any data is, and must not import the engine for that.
"""
from __future__ import annotations

LEVELS = ("mount", "patch", "triangle")

# the kinds of residual rows (:mod:`nao_skin.calibration.pairing` explains each)
KIND_COP, KIND_TAXEL, KIND_TAXEL5 = 0, 1, 2
KIND_NORMAL = 3   # solver-only rows (rows.with_normal_rows): the two contacts' mean normals must cancel
KIND_CONTACT_TAXEL = 4   # reported only: the closest taxel pair of the two selected contacts (kind 1 of "contacts")
KIND_PLANE_B, KIND_PLANE_A = 5, 6   # solver-only: A's taxels against B's surface, B's against A's
KIND_SURFACE = 7   # solver-only: every activated taxel against the other part's skin (calibration.contact)
KIND_COP_SKIN = 8  # the closest COP pair, each COP over its taxels with the other part's skin beside them
KIND_FINGERTIP = 9  # a fingertip touch: the COP of the contact nearest the fingertip, at the fingertip's sphere
# how a touch's point-to-plane rows are weighted: each 1; 1/sqrt(n) each (a touch's rows of one
# direction weigh as much as one row, however many taxels fire); sqrt of the taxel's share of its
# contact's pressure (the same total, central taxels more)
PLANE_WEIGHTS = ("equal", "touch", "pressure")
