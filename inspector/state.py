"""A prepared state of the inspector, as URL query parameters (a "prepared link"). Pure.

    http://127.0.0.1:8080/?set=tabletop_ball&ref=cam03&off=cam05&threshold=0.45&pixel=212,148&step=4

| key | value |
| --- | --- |
| set | the set's name (a warning when the inspector serves another set) |
| preset | default, paper or peer-homography |
| ref | the reference photo's stem |
| off | supports switched off, stems separated by commas (empty: all on) |
| threshold | the threshold, in [0, 1] |
| pixel | the explained point, "x,y" in working-resolution pixels (as the Pixel tab shows them) |
| step | the tour's step, 1 to 7 (absent or 0: no tour) |
| support | the support the tour's steps 2 to 5 show |
| presenter | 1: presenter mode |

Every key is optional; what a link leaves out stays as it is.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from urllib.parse import parse_qsl, quote, urlencode

N_STEPS = 7


@dataclass(frozen=True)
class PreparedState:
    set: str | None = None
    preset: str | None = None
    ref: str | None = None
    off: tuple[str, ...] | None = None
    threshold: float | None = None
    pixel: tuple[float, float] | None = None
    step: int | None = None
    support: str | None = None
    presenter: bool | None = None

    def is_empty(self) -> bool:
        return all(v is None for v in dataclasses.asdict(self).values())


def to_query(st: PreparedState) -> str:
    """The state as a query string (without '?'), keys in the documented order."""
    items = []
    for f in dataclasses.fields(st):
        v = getattr(st, f.name)
        if v is None:
            continue
        if f.name == "off":
            v = ",".join(v)
        elif f.name == "pixel":
            v = f"{v[0]:.0f},{v[1]:.0f}"
        elif f.name == "threshold":
            v = f"{v:.3f}".rstrip("0").rstrip(".") or "0"
        elif f.name == "presenter":
            v = "1" if v else "0"
        items.append((f.name, str(v)))
    return urlencode(items, safe=",", quote_via=quote)


def from_query(query: str) -> PreparedState:
    """Parse a query string (with or without '?', or a whole link). Raises ValueError naming the
    key whose value is wrong; unknown keys are errors too (a typo must not pass silently)."""
    q = query.strip()
    if "?" in q:
        q = q.split("?", 1)[1]
    q = q.split("#", 1)[0]
    names = {f.name for f in dataclasses.fields(PreparedState)}
    kw: dict = {}
    for key, value in parse_qsl(q, keep_blank_values=True):
        if key not in names:
            raise ValueError(f"unknown key {key!r} (known: {', '.join(sorted(names))})")
        try:
            if key == "off":
                kw[key] = tuple(s for s in (x.strip() for x in value.split(",")) if s)
            elif key == "threshold":
                t = float(value)
                if not 0.0 <= t <= 1.0:
                    raise ValueError
                kw[key] = t
            elif key == "pixel":
                x, y = (float(v) for v in value.split(","))
                kw[key] = (x, y)
            elif key == "step":
                s = int(value)
                if not 0 <= s <= N_STEPS:
                    raise ValueError
                kw[key] = s
            elif key == "presenter":
                if value not in ("0", "1", "true", "false"):
                    raise ValueError
                kw[key] = value in ("1", "true")
            else:
                if not value:
                    raise ValueError
                kw[key] = value
        except ValueError:
            raise ValueError(f"bad value for {key!r}: {value!r}") from None
    return PreparedState(**kw)
