"""`python -m proxybench`: the command line without the console script on PATH (as `proxybench serve` starts
its evaluators)."""

from proxybench.cli import main

if __name__ == "__main__":
    main()
