from courtloc.cli import main

main()
