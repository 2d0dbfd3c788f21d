"""Progress display for long work: a tqdm bar on a terminal, sparse log lines otherwise."""
from __future__ import annotations

import sys

from tqdm import tqdm

__all__ = ["Progress"]


class Progress:
    """``progress(stage, done, total)`` callable that keeps one bar per stage.

    Parameters
    ----------
    enabled : bool
        False silences it (``--quiet``).
    units : dict, optional
        Stage -> what one step is (default "frame").
    """

    def __init__(self, enabled: bool = True, units: dict | None = None):
        self.enabled = enabled
        self.units = dict(units or {})
        self._bars = {}

    def __call__(self, stage: str, done: int, total: int, **postfix) -> None:
        if not self.enabled:
            return
        bar = self._bars.get(stage)
        if bar is None:
            bar = tqdm(total=total, desc=f"{stage:>12s}", unit=self.units.get(stage, "frame"), file=sys.stderr, leave=True,
                       mininterval=0.5 if sys.stderr.isatty() else 5.0, dynamic_ncols=True)
            self._bars[stage] = bar
        bar.update(done - bar.n)
        if postfix:
            bar.set_postfix(postfix, refresh=False)
        if done >= total:
            bar.close()

    def close(self) -> None:
        for bar in self._bars.values():
            bar.close()
