"""Progress bars for the long parts of a run, from tqdm: a bar on a terminal, a widget in a
notebook (text there without ipywidgets), and nothing where nobody watches (a log file, a
pipe, a batch job), so logs get no carriage-return soup."""

from __future__ import annotations

import sys
import warnings


def interactive():
    """Whether someone watches: a Jupyter kernel, or stderr a terminal."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    if shell is not None and "IPKernelApp" in getattr(shell, "config", {}):
        return True
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def progress_bar(total, desc, unit="it", enabled=True):
    """A tqdm bar of `total` steps (`.update(n)`, `.set_postfix_str(s)`, `.close()`),
    disabled when not `enabled` (a caller's `progress=False`) or not `interactive()`."""
    with warnings.catch_warnings():
        # without ipywidgets, tqdm.auto warns in a notebook and falls back to text
        warnings.simplefilter("ignore")
        from tqdm.auto import tqdm
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        disable=not (enabled and interactive()),
        file=sys.stderr,
        dynamic_ncols=True,
    )


def advance(bar, label):
    """One step of `bar` done, with `label` shown beside it."""
    bar.set_postfix_str(label, refresh=False)
    bar.update(1)
