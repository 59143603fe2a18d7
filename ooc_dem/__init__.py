"""ooc-dem: out-of-core 2D DEM of soil-wheel interaction (Nakashima 2008, serial DDM)."""
__version__ = "0.1.0"
