"""Keys, certificates, access rules and model signatures for a robot's bus (`courtloc secure ...`)."""
