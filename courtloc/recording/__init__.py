"""Pit tools that store the bus: `courtloc record`, `courtloc replay`, `courtloc dataset capture`."""
