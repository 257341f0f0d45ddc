"""Progress lines on stderr: rewritten in place on a terminal, sparse full lines in logs."""

from __future__ import annotations

import sys
import warnings


class Progress:
    def __init__(self, label: str, total: int, enabled: bool = True):
        self.label, self.total, self.enabled = label, max(int(total), 1), enabled
        self.tty = sys.stderr.isatty()
        self._last_pct = -1

    def update(self, done: int, extra: str = "") -> None:
        if not self.enabled:
            return
        pct = int(100 * done / self.total)
        msg = f"[{self.label}] {done}/{self.total}" + (f" {extra}" if extra else "")
        if self.tty:
            print("\r" + msg, end="\n" if done >= self.total else "", file=sys.stderr, flush=True)
        elif done >= self.total or pct >= self._last_pct + 25:
            self._last_pct = pct
            print(msg, file=sys.stderr, flush=True)


def stage_logger(enabled: bool = True, every: int = 1):
    """A ``log(stage, it, loss)`` callable printing one line per ``every`` iterations on stderr, or None."""
    if not enabled:
        return None

    def log(stage: str, it: int, loss: float) -> None:
        if it % every == 0:
            print(f"[{stage}] iter {it} loss {loss:.6g}", file=sys.stderr, flush=True)

    return log


def warn(message: str | None, verbose: bool, label: str = "run") -> None:
    """A warning (nothing for None): a ``[label] warning: ...`` line on stderr when ``verbose``, else through
    :mod:`warnings` (which a quiet run still shows once, and a library caller can filter)."""
    if message is None:
        return
    if verbose:
        print(f"[{label}] warning: {message}", file=sys.stderr, flush=True)
    else:
        warnings.warn(message, RuntimeWarning, stacklevel=3)
