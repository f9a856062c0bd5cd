"""Evaluation: the paper's metrics, classical baselines, and running methods over a protocol split."""
