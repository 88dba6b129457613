"""proxybench: develop, benchmark and measure the usefulness of simulators for Duckietown-style agents."""

__version__ = "0.1.0"
