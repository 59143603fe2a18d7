"""3D (sphere) kernels: layout, contact law, neighbours, forces, step, time step, and a
thin test driver (sim). The spec-generic entry points are ``step.run_steps`` and
``step.spatial_order``."""
