"""What the step machinery knows of a dimension's axes: names its templates leave to each
dimension (``twins.Slot``, bound by ``step.instantiate`` and ``neighbors.instantiate``).
Axis a of a position, velocity or force is column a (``layout.AX_X``, ``AX_Y``,
``AX_Z``); the machinery loops over range(DIM), so 2D and 3D run the same source."""

from .twins import slot

DIM = slot("DIM: the axes D of a position, velocity and force (2 or 3)")
SPIN = slot("SPIN: the components R of a spin and a torque (2D: 1, about z; 3D: 3)")
vec = slot("vec(v): the D entries of a vector, as a tuple")
