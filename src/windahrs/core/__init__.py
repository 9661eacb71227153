"""The estimator core: the compiled state records, process models and Kalman updates that
every aid source (windahrs.aid) and every estimator (windahrs.filters) runs on."""
