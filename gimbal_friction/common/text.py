"""Plain-text and JSON output shared by commands and library reports: tables, CSV, JSON with nulls for non-finite,
the "did you mean" hint of an unknown name."""

from __future__ import annotations

import csv
import difflib
import io
import math
from collections.abc import Iterable, Mapping
from typing import Any


def json_finite(obj: Any) -> Any:
    """``obj`` with every non-finite float (nested in mappings and sequences) replaced by None (JSON null)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: json_finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_finite(v) for v in obj]
    return obj


def csv_text(records: Iterable[Mapping[str, Any]], fields: list[str]) -> str:
    """CSV with a header row."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator='\n')
    writer.writeheader()
    for rec in records:
        writer.writerow({k: rec[k] for k in fields})
    return buf.getvalue()


def format_table(rows: list[list[str]], header: list[str]) -> str:
    """Right-aligned plain-text table."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    line = '  '.join(h.rjust(w) for h, w in zip(header, widths, strict=True))
    out = [line, '  '.join('-' * w for w in widths)]
    out += ['  '.join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return '\n'.join(out)


def did_you_mean(name: str, known: Iterable[str], *, same_first_word: bool = False) -> str:
    """The hint appended to an unknown-name error: `` (did you mean 'x'?)`` or empty. The nearest spelling among
    ``known`` (difflib ratio >= 0.75), or with ``same_first_word`` the first of ``known`` whose first
    ``_``-separated word is ``name``'s (a model or simulator parameter of the same family).

    >>> did_you_mean('rate_loop', ['rate_loop_hz', 'seed'])
    " (did you mean 'rate_loop_hz'?)"
    >>> did_you_mean('walther_x', ['seed', 'walther_a'], same_first_word=True)
    " (did you mean 'walther_a'?)"
    >>> did_you_mean('zzz', ['seed'])
    ''
    """
    if same_first_word:
        family = name.split('_', maxsplit=1)[0]
        close = [n for n in known if n.split('_', maxsplit=1)[0] == family]
    else:
        close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.75)
    return f' (did you mean {close[0]!r}?)' if close else ''
