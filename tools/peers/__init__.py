"""Peer cross-checks: the same bed and contact law run by another DEM code, side by side."""
