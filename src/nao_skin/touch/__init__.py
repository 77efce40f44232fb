"""Touches as flat arrays, contacts, the self-touch event detector, data sets."""

# metres, skinManager's default maxNeighborDist: here, without numpy, as the simulator's parameters (read
# for nao-skin simulate --help) take it as their default
DEFAULT_MAX_NEIGHBOR_DIST = 0.012

# m: a fingertip this close to the taxels a part fired alone pressed them (touch.fingertip.FingertipJudge): the real
# torso's nominal skin puts the fingertip 12.6 mm (mean) from its contact, an experimenter's hand is centimetres off
DEFAULT_FINGERTIP_GATE = 0.03
