"""Touches as flat arrays, contacts, the self-touch event detector, data sets."""
