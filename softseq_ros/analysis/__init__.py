"""Metrics and figures from bags and experiment files."""
