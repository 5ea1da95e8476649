"""Missions shipped with the package (``pmht_opt/data``), by name."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pmht_opt.exceptions import ConfigError
from pmht_opt.io.mission import Mission, load_mission

#: The example missions: name -> one line on what it is.
EXAMPLES = {
    "survey": "36 survey sites over about 3 x 2.5 km near Canberra, three drones from three launch "
    "points, a 10 m/s speed limit, return to base",
}


def example_path(name: str) -> Path:
    """The file of the example mission ``name``."""
    if name not in EXAMPLES:
        raise ConfigError(f"example: expected one of {', '.join(EXAMPLES)}, got {name!r}.")
    return Path(str(resources.files("pmht_opt.data").joinpath(f"{name}.toml")))


def example_mission(name: str) -> Mission:
    """The example mission ``name``, loaded."""
    return load_mission(example_path(name))
