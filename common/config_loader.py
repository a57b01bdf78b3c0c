"""Reading a deployment file (TOML, or JSON as written by the launcher) into a pydantic model.

A bad file stops the process before it touches the bus, with the file, the field and the bad value.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - the Jetson's Python 3.10
    import tomli as tomllib

C = TypeVar("C", bound=BaseModel)


class ConfigError(ValueError):
    """A config file that cannot be used; the message names file, field and value."""


def read_mapping(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"config error in {path}: cannot read file: {exc.strerror}") from None
    try:
        data = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"config error in {path}: not valid {path.suffix.lstrip('.') or 'TOML'}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"config error in {path}: top level must be a table")
    return data


def describe_validation_error(source: str, exc: ValidationError) -> str:
    lines = [f"config error in {source}:"]
    for err in exc.errors():
        field = ".".join(str(p) for p in err["loc"]) or "(top level)"
        value = err.get("input")
        shown = "" if isinstance(value, dict) else f" (got {value!r})"
        lines.append(f"  field {field}: {err['msg']}{shown}")
    return "\n".join(lines)


def load_model(path: Path | None, model: type[C]) -> C:
    """The model's defaults when `path` is None (the built-in default deployment)."""
    data = {} if path is None else read_mapping(Path(path))
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(describe_validation_error(str(path or "built-in defaults"), exc)) from None


def resolve_relative_paths(model: C, base_dir: Path) -> C:
    """A copy where every relative Path field, at any depth, is taken relative to `base_dir`
    (the config file's folder), so a deployment means the same thing from any working directory."""
    updates: dict[str, Any] = {}
    for name in type(model).model_fields:
        value = getattr(model, name)
        if isinstance(value, Path) and not value.is_absolute():
            updates[name] = (base_dir / value).resolve()
        elif isinstance(value, BaseModel):
            resolved = resolve_relative_paths(value, base_dir)
            if resolved is not value:
                updates[name] = resolved
    return model.model_copy(update=updates) if updates else model
