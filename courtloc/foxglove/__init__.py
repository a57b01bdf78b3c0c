"""Foxglove: the official message schemas as JSON (for MCAP files and the live server), the 3D scene of a
robot on its court, and `courtloc foxglove`, a live Foxglove WebSocket server on the pit laptop."""
