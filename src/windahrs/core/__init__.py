"""The generic compiled (numba) filter core: dense Kalman and unscented-transform steps."""
