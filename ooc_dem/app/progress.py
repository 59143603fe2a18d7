"""What a run shows on stderr while it works: the settling of its bed, then a bar over its
steps (tqdm). Off unless asked for (the API's default; the CLI's is on)."""

from __future__ import annotations

import sys
import time
from typing import Any

from ..model.scenario import Scenario
from .bed import SettleProgress


class Progress:
    """tqdm bar over simulated time, with steps/s; silent when disabled."""

    def __init__(self, enabled: bool, total_steps: int, dt: float, label: str):
        self.bar: Any = None  # a tqdm bar (tqdm is untyped here)
        self.dt = dt
        if enabled and total_steps > 0:
            from tqdm import tqdm

            self.bar = tqdm(
                total=total_steps,
                desc=label,
                unit="step",
                unit_scale=True,
                mininterval=1.0,
                file=sys.stderr,
                dynamic_ncols=True,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} steps "
                "[{elapsed}<{remaining}, {rate_fmt}] {postfix}",
            )

    def update(self, step: int, n: int, **post: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(
                f"t={step * self.dt:.4f} s " + " ".join(f"{k}={v}" for k, v in post.items()), refresh=False
            )
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def kernels_cached(dim: int) -> bool:
    """Whether numba's cache holds this dimension's step kernel (False: the first step
    compiles the kernels, a few minutes). True when it cannot tell."""
    import os

    from ..physics import kernels

    try:
        step: Any = kernels(dim).run_steps
        index = step._cache._cache_file._index_path  # numba's cache index file
    except AttributeError:
        return True
    return bool(os.path.exists(index))


COMPILING = (
    "compiling the kernels: the first run on this machine takes a few minutes before its first step "
    "(later runs load them from numba's cache)"
)


def settling_progress(sc: Scenario) -> SettleProgress:
    """The bed's settling as one line on stderr, rewritten at most once a second: the settling
    time reached and the mean speed against the scenario's target (bed.settle_speed)."""
    state = {"last": 0.0}

    def cb(t: float, speed: float) -> None:
        if time.time() - state["last"] > 1.0:
            state["last"] = time.time()
            print(
                f"\rsettling bed: t = {t:.3f} s, mean speed {speed:.2e} m/s (target {sc.bed.settle_speed:.1e})",
                end="",
                file=sys.stderr,
                flush=True,
            )

    return cb
