"""The 3D step kernels (spheres; x = travel, y = vertical, z = across the bin): the
per-dimension entry points the engine calls (``physics.kernels(3)``), ``run_steps`` (and
its one-thread twin ``run_steps_serial``, with ``sync_history_serial`` for serial DDM's
compiled sweeps) and ``spatial_order``, and the row layouts the engine sizes its buffers with (``PAIR_ROW``
or ``pair_row_layout(cp)``, ``BODY_ROW``, ``N_ERR``, ``N_CHUNKS``). Modules: layout, contact law, neighbours,
forces, step, time step, and a thin test driver (sim)."""
from .forces import N_CHUNKS  # noqa: F401
from .layout import (BODY_ROW, CONTACT_PARAMS, N_ERR, PAIR_ROW,  # noqa: F401
                     WALLS, pair_row_layout)
from .forces import sync_history_serial  # noqa: F401  (serial DDM's write-back, engine.live)
from .step import run_steps, run_steps_serial, spatial_order  # noqa: F401

DIM = 3
