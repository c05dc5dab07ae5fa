"""Learning-rate schedules in SB3's convention: a callable of ``progress_remaining`` (1 at the start, 0 at the end)."""

from __future__ import annotations


class StepSchedule:
    """Piecewise-constant schedule: ``initial_value`` until ``switch_fraction`` of training has elapsed, then
    ``final_value``.

    :param initial_value: value for the first part of training
    :param final_value: value afterwards
    :param switch_fraction: elapsed fraction of training (0..1) after which ``final_value`` is used
    """

    def __init__(self, initial_value: float, final_value: float, switch_fraction: float):
        if not 0.0 <= switch_fraction <= 1.0:
            raise ValueError(f"switch_fraction must be in [0, 1], got {switch_fraction}")
        self.initial_value = float(initial_value)
        self.final_value = float(final_value)
        self.switch_fraction = float(switch_fraction)

    def __call__(self, progress_remaining: float) -> float:
        elapsed = 1.0 - progress_remaining
        # the tolerance makes "the first k of n updates" exact when switch_fraction = k / n
        return self.initial_value if elapsed <= self.switch_fraction + 1e-9 else self.final_value

    def __repr__(self) -> str:
        return f"StepSchedule({self.initial_value}, {self.final_value}, switch_fraction={self.switch_fraction})"


def paper_learning_rate(total_updates: int = 1600, switch_update: int = 1000) -> StepSchedule:
    """The paper's schedule (Sec. IV): 1e-4 for the first ``switch_update`` updates, 1e-5 after.

    SB3 schedules see the fraction of training elapsed, not an update count, so the switch happens after
    ``switch_update / total_updates`` of the timesteps given to ``learn``: exact for the paper's 1600 updates, and
    proportionally earlier or later for other budgets.

    :param total_updates: number of rollout/update iterations the training will run (paper: 1600)
    :param switch_update: number of updates at 1e-4 (paper: 1000)
    """
    if total_updates < 1 or not 0 <= switch_update <= total_updates:
        raise ValueError(
            f"paper_learning_rate needs total_updates >= 1 and 0 <= switch_update <= total_updates, "
            f"got total_updates={total_updates}, switch_update={switch_update}"
        )
    return StepSchedule(1e-4, 1e-5, switch_update / total_updates)
