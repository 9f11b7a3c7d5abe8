"""Whose a stored row is: a row evaluated with another registry's model (a researcher's
own registry) is never replaced by a rebuild that does not load that registry.
"""

from __future__ import annotations

import json
from pathlib import Path

from zoo.core.io import registry_record, repo_relative
from zoo.store.layout import StoreError


def stored_provenance(folder: Path) -> dict:
    return json.loads((folder / "protocol.json").read_text()).get("provenance", {})


def recorded_registry(folder: Path) -> str | None:
    provenance = stored_provenance(folder)
    identity = provenance.get("identity") or {}
    return (identity.get("model") or {}).get("registry") or provenance.get("registry")


def refuse_foreign_registry(folder: Path, loaded, label: str) -> None:
    """A stored row of this label made with another registry's model is the user's: never
    replaced by a rebuild that does not load that registry."""
    recorded = recorded_registry(folder)
    # rows recorded before registry_record named an outside registry by its absolute path
    if recorded is not None and recorded not in (
        registry_record(loaded.entry.source),
        repo_relative(loaded.entry.source),
    ):
        raise StoreError(
            f"{folder}: row {label!r} was evaluated with registry {recorded}, which "
            f"this run does not load (its {label!r} comes from "
            f"{registry_record(loaded.entry.source)}); nothing was changed: pass "
            f"--registry with that file, or remove the row deliberately with --drop "
            f"{label}"
        )
