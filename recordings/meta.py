"""Run metadata: what a recording is a recording of (MCAP Metadata record ``hexbench``)."""

from __future__ import annotations

import json
import platform
import sys
from importlib import metadata as importlib_metadata
from typing import Any, Mapping

from bus.messages import RunMeta

#: Name of the MCAP metadata record that describes the run.
METADATA_NAME = "hexbench"
#: Name of the MCAP metadata record with the recorder's counts (written when a file is closed).
STATS_NAME = "hexbench.stats"

_TEXT_KEYS = frozenset({"scenario", "profile", "planner", "clock", "fleet", "start_time"})
_PACKAGES = ("hexbench", "eclipse-zenoh", "mcap", "rerun-sdk", "foxglove-sdk", "zstandard", "lz4")


def iso_time(t_ns: int) -> str:
    """An instant as ISO 8601 UTC with milliseconds (``2026-11-25T01:02:03.456Z``)."""
    from datetime import datetime, timezone
    dt = datetime.fromtimestamp(t_ns // 1_000_000 / 1000, tz=timezone.utc)
    return dt.strftime("%Y-%m-%dT%H:%M:%S.") + f"{dt.microsecond // 1000:03d}Z"


def package_versions() -> dict[str, str]:
    """Versions of the packages a recording depends on (absent ones are left out)."""
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            pass
    return out


def base_metadata(fleet: str, argv: list[str] | None = None) -> dict[str, Any]:
    """What the recorder knows by itself: fleet, its command line and package versions."""
    return {"fleet": fleet, "recorder_argv": list(sys.argv if argv is None else argv),
            "versions": package_versions()}


def merge(*parts: Mapping[str, Any] | RunMeta | None) -> dict[str, Any]:
    """Later parts win; a :class:`RunMeta` counts as its fields. Version maps are merged."""
    out: dict[str, Any] = {}
    for part in parts:
        if part is None:
            continue
        d = part.to_dict() if isinstance(part, RunMeta) else dict(part)
        d.pop("type", None)
        versions = {**out.get("versions", {}), **(d.pop("versions", None) or {})}
        out.update(d)
        if versions:
            out["versions"] = versions
    return out


def to_mcap(meta: Mapping[str, Any]) -> dict[str, str]:
    """MCAP metadata is str -> str: strings stay, everything else becomes JSON."""
    return {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True) for k, v in meta.items()}


def from_mcap(data: Mapping[str, str]) -> dict[str, Any]:
    """Inverse of :func:`to_mcap` (strings that are not JSON stay strings)."""
    out: dict[str, Any] = {}
    for k, v in data.items():
        if k in _TEXT_KEYS:  # a scenario named "12" is still a name
            out[k] = v
            continue
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out
