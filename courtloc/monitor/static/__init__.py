"""Static files of the monitor page (a package so that they ship in the wheel)."""
