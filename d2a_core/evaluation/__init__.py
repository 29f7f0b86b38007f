"""Evaluation: per-episode metrics from env infos, aggregation, evaluation runs."""
