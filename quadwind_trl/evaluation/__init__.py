"""Metrics, paired evaluation, statistics and figures."""
