"""windahrs: UAV attitude estimation in wind."""
