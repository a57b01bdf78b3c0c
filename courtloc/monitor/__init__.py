"""`courtloc monitor`: a live web page of one robot, served from the pit laptop."""
