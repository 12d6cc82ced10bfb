"""`--set key=value` overrides shared by the command-line tools."""

from __future__ import annotations

from collections.abc import Iterable

from mjxrow.field import PARAM_NAMES


def parse_sets(items: Iterable[str] | None, known: Iterable[str] = PARAM_NAMES) -> dict[str, float]:
    """['d_rr=2.0', 'terrain_dh=0.1'] → {'d_rr': 2.0, 'terrain_dh': 0.1}.

    Raises ValueError naming the offending item: missing '=', unknown key, non-numeric value."""
    known = tuple(known)
    out: dict[str, float] = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep:
            raise ValueError(f"--set {item!r}: expected key=value")
        if key not in known:
            raise ValueError(f"--set {key}: unknown parameter; known: {', '.join(known)}")
        try:
            out[key] = float(value)
        except ValueError:
            raise ValueError(f"--set {key}: value {value!r} is not a number") from None
    return out
