"""Progress bars and tables of the ``scet`` command (the CLI layer: the library never prints)."""

from __future__ import annotations

import sys


def print_table(rows: list[list[str]], header: list[str], out=None) -> None:
    out = sys.stdout if out is None else out
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    fmt = "  ".join(f"{{:>{w}}}" for w in widths)
    print(fmt.format(*header), file=out)
    for row in rows:
        print(fmt.format(*row), file=out)


def progress_bar(total: int, unit: str, desc: str):
    """A tqdm bar on stderr with time left, as a ``progress(done, total)`` callback."""
    from tqdm import tqdm

    bar = tqdm(total=total, unit=unit, desc=desc, dynamic_ncols=True, disable=None)

    def update(done: int, total_now: int, *_):
        bar.total = total_now
        bar.n = done
        bar.refresh()

    return bar, update


class StageBars:
    """Progress bars for a job made of named stages: one bar per stage, the previous closed when
    the next starts. ``update(stage, done, total, label="")`` is the job's progress callback."""

    def __init__(self):
        self.name, self.bar, self.set = None, None, None

    def update(self, stage, done, total, label=""):
        if stage != self.name:
            self.close()
            self.name = stage
            self.bar, self.set = progress_bar(total, "step", stage)
        if label:
            self.bar.set_postfix_str(str(label)[:40], refresh=False)
        self.set(done, total)

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None
