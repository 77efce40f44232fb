"""The self-touch simulator with ground truth."""
