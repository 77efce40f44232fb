"""The benchmark: strategies against error, hard cases, live updates, capture, the linearised bound."""

# what every bench judges a simulated calibration by: each calibrated part's true taxel error (mm), median
# and 95th percentile (the issues' target)
TARGET_MM = {"median": 0.5, "p95": 1.5}
