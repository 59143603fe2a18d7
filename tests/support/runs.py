"""Small runs the tests share: the short wheel run's overrides and the base run's length."""

# a short wheel run on the quick rig: 0.1 s of settling, 0.4 s of travel
WHEEL_TEST = [
    "wheel.settle_time=0.1",
    "wheel.travel_time=0.4",
    "wheel.drawbar_ramp=0.1",
    "output.steady_start=0.1",
    "output.steady_end=0.4",
]

# the base_run fixture's length and checkpoint interval: its current epoch is at BASE_RUN_STEPS
BASE_RUN_STEPS = 40
BASE_RUN_CKPT = 20
