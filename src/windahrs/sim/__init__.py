"""Flight, wind and sensor simulation."""
