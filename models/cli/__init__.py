"""Every `magnet` sub-command: argument parsing, progress and one-line errors over the Python API.
Imports anything in models; nothing in models imports it."""

from models.cli.main import main

__all__ = ["main"]
