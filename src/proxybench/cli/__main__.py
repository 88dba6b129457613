"""`python -m proxybench.cli`: the command line without the console script on PATH."""

from proxybench.cli import main

main()
