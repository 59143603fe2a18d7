"""The 2D step kernels (discs in the x-y plane, spin about z): the dimension's kernel
module (``physics.kernels(2)``; its names are ``physics.KernelModule``'s).

The step machinery is ``physics``'s, written once (``physics.step``); this package holds
only what is 2D's own and binds it there: the records (``layout``), the contact law
(``contact``), the pair law on blocks and what a 2D contact row holds (``forces``), the
walls' and the wheel's contact geometry (``bodies``) and the cell geometry of the
neighbour build (``neighbors``).
"""

import sys

from .. import check_kernel_module
from ..chunks import N_CHUNKS  # noqa: F401
from ..layout import N_ERR  # noqa: F401
from ..step import instantiate
from . import bodies, forces, layout, neighbors
from .layout import BODY_ROW, CONTACT_PARAMS, DIM, PAIR_ROW, WALLS, pair_row_layout  # noqa: F401
from .neighbors import build_pairs, spatial_order  # noqa: F401

# the phases, run_steps and their one-thread twins (physics.step.instantiate)
globals().update(vars(instantiate("d2", layout, forces, bodies, neighbors)))
check_kernel_module(sys.modules[__name__])
