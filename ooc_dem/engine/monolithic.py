"""The monolithic engine: the whole bin as one domain advanced in place (one copy of the
state: the fair memory baseline)."""

from __future__ import annotations

import numpy as np

from ..model.checkpoint import particles_to_record, read_all_particles
from ..physics.layout import AX_X
from ..model.state import Particles
from .interface import write_epoch
from .stepper import DomainStepper, Model


class MonolithicEngine:
    """The whole bin as one domain, advanced in place."""

    name = "monolithic"
    preferred_chunk = 2000
    epoch_each_advance = False
    writes_frame_parts = False

    def __init__(self, particles: Particles, wheel_state: np.ndarray, model: Model, store=None, redecompositions=()):
        self.model = model
        self.stepper = DomainStepper(particles, model, wheel_state)
        self.resident_max = len(particles)
        self.store = store  # where `commit` writes its epochs (None: no commits)
        self.redecompositions = list(redecompositions)

    @classmethod
    def default_block(cls, sc, domains: int) -> int:
        return 1

    @classmethod
    def create(
        cls,
        sc,
        model: Model,
        particles: Particles,
        wheel_state: np.ndarray,
        *,
        domains: int = 1,
        block: int = 1,
        store=None,
    ) -> "MonolithicEngine":
        """The whole bed as one domain (one sub-domain, one step a block)."""
        return cls(particles, wheel_state, model, store=store)

    @classmethod
    def reopen(
        cls, sc, model: Model, reader, wheel_state: np.ndarray, engine_attrs=None, *, store, redecompositions=()
    ) -> "MonolithicEngine":
        """Continue from the committed epoch ``reader`` reads: all of its groups in RAM."""
        particles = read_all_particles(reader, model.dim, model.hist_cap)
        return cls(particles, wheel_state, model, store=store, redecompositions=redecompositions)

    def advance(self, step0: int, nsteps: int, frame=None) -> np.ndarray:
        return self.stepper.advance(step0, nsteps)

    @property
    def wheel_state(self) -> np.ndarray:
        return self.stepper.ws

    def particles(self) -> Particles:
        return self.stepper.p

    def n_discs(self) -> int:
        return len(self.stepper.p)

    def state_parts(self, names=()):
        yield self.stepper.p

    def write_domains(self, writer) -> None:
        p = self.stepper.p
        order = np.argsort(p.pos[:, AX_X], kind="stable")
        q = p.take(order)
        attrs = {"xmin": float(q.pos[0, AX_X]) if len(q) else 0.0, "xmax": float(q.pos[-1, AX_X]) if len(q) else 0.0}
        writer.write_domain(0, particles_to_record(q), attrs)

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        write_epoch(self.store, step, self.write_domains, arrays, attrs, durable)

    def info(self) -> dict:
        return {"resident_max": self.resident_max, "neighbour_rebuilds": self.stepper.rebuilds}
