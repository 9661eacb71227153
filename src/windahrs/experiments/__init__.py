"""Experiments: Monte Carlo runs of estimators on simulated flights, and the paper's
reproduction."""
