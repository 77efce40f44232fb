"""Touches as flat arrays, contacts, the self-touch event detector, data sets."""

# metres, skinManager's default maxNeighborDist: here, without numpy, as the simulator's parameters (read
# for nao-skin simulate --help) take it as their default
DEFAULT_MAX_NEIGHBOR_DIST = 0.012
