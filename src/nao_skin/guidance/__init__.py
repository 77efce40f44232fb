"""Guided capture: where touches would add most to the calibration, and the poses that get there."""
