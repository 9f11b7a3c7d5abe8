"""Whether rows may share a table: two protocol records are comparable when all but their
provenance agree; rows whose records differ raise :class:`ProtocolMismatchError`, which names
the fields that differ.
"""

# zoo: computes no number

from __future__ import annotations

from typing import Any

from zoo.core.errors import ZooError


class ProtocolMismatchError(ZooError, ValueError):
    pass


def _comparable(record: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in record.items() if k not in ("provenance", "protocol_id")}


def protocol_differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Human-readable differences between the comparable parts of two protocol records."""
    a, b = _comparable(a), _comparable(b)
    out = []
    for key in sorted(set(a) | set(b)):
        if a.get(key) == b.get(key):
            continue
        if key == "files" and isinstance(a.get(key), list) and isinstance(b.get(key), list):
            fa = {f["file"]: f.get("sha256") for f in a[key]}
            fb = {f["file"]: f.get("sha256") for f in b[key]}
            only_a, only_b = sorted(set(fa) - set(fb)), sorted(set(fb) - set(fa))
            changed = sorted(f for f in set(fa) & set(fb) if fa[f] != fb[f])
            parts = [
                f"only in first: {only_a}" if only_a else "",
                f"only in second: {only_b}" if only_b else "",
                f"different sha256: {changed}" if changed else "",
            ]
            out.append("files (" + "; ".join(p for p in parts if p) + ")")
        else:
            out.append(f"{key} ({a.get(key)!r} vs {b.get(key)!r})")
    return out


def check_comparable(records: dict[str, dict[str, Any]]) -> None:
    """Raise unless every record has the same comparable part."""
    items = list(records.items())
    for pid, record in items[1:]:
        diff = protocol_differences(items[0][1], record)
        if diff:
            first = items[0][1].get("provenance", {}).get("model", items[0][0])
            second = record.get("provenance", {}).get("model", pid)
            raise ProtocolMismatchError(
                f"refusing to put rows of different protocols in one table: protocol "
                f"{items[0][0]} ({first}) and {pid} ({second}) differ in " + "; ".join(diff)
            )
