"""Progress lines on stderr: rewritten in place on a terminal, sparse full lines in logs."""

from __future__ import annotations

import sys


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
