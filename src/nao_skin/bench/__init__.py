"""The benchmark: strategies against error, hard cases."""
