"""The base of every error ooc-dem raises for a user to see.

Each layer defines its own errors (``ScenarioError``, ``StoreError``, ``RunError`` ...), all
subclasses of ``OocDemError``; some keep a second base (``ValueError``, ``RuntimeError``)
that callers catch them by. The command line catches ``OocDemError`` and prints its
message after ``ooc-dem: error:`` (exit code 2).

This module sits below every layer, storage included, and imports nothing of ooc_dem.
"""


class OocDemError(Exception):
    """An error for the user: its message (``str(e)``) is one line naming what is wrong
    (the file, key or value, and what is allowed), as the command line prints it."""
