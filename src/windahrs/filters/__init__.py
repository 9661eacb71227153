"""Estimators: the paper's filter and its baselines, the error-state filters that beat
them, and the registry that names them all."""
