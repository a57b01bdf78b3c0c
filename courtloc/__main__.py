from courtloc.cli import run

run()
