"""The benchmark: strategies against error, hard cases, live updates, capture, the linearised bound."""

# what every bench judges a simulated calibration by: each calibrated part's true taxel error (mm), median
# and 95th percentile (the issues' target; the live status's "done" is judged by it too)
from nao_skin.live.updates import TARGET_MM  # noqa: F401
