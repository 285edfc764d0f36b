"""The daemon's files it cannot read: the checks of :mod:`compd.files.unreadable`, as the store names them."""

from __future__ import annotations

# The checks live with the files they read (compd.files.unreadable: the probe state is read
# there too); the daemon's store names them here.
from compd.files.unreadable import MAX_DIGITS, finite, json_int, set_aside, whole

__all__ = ["MAX_DIGITS", "finite", "json_int", "set_aside", "whole"]
