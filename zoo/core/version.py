"""The package version, in a module that imports nothing of the zoo (so that recording it never
imports the package and everything it pulls in)."""

__version__ = "0.1.0"
