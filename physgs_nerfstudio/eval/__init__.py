"""Evaluation: metrics (metrics.py) and dataset adapters."""
