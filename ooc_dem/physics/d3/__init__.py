"""The 3D step kernels (spheres; x = travel, y = vertical, z = across the bin): the
per-dimension entry points the engine calls (``physics.kernels(3)``), ``run_steps`` (and
its one-thread twin ``run_steps_serial`` with what serial DDM's compiled sweeps take of a
dimension: ``SWEEP_KEEPS_ROWS``, ``sweep_sync_history``) and ``spatial_order``, and the row layouts the engine sizes its buffers with (``PAIR_ROW``
or ``pair_row_layout(cp)``, ``BODY_ROW``, ``N_ERR``, ``N_CHUNKS``). Modules: layout, contact law, neighbours,
forces, step, time step, and a thin test driver (sim)."""
from .forces import N_CHUNKS  # noqa: F401
from .layout import (BODY_ROW, CONTACT_PARAMS, N_ERR, PAIR_ROW,  # noqa: F401
                     WALLS, pair_row_layout)
from .step import (SWEEP_KEEPS_ROWS, run_steps, run_steps_serial,  # noqa: F401
                   spatial_order, sweep_sync_history)

DIM = 3
