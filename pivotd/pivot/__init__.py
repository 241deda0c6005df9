"""PIVOT optimizer: pure numpy, no I/O, no threads, no globals."""
