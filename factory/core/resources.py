"""Where the data that ships with factory lives (tool library, cells, camera, message definitions, migrations).

Every folder is found through :mod:`importlib.resources` inside the ``factory`` package, so the
same lookup serves a checkout and an installed wheel. In a checkout, ``factory/fixtures``,
``factory/ros`` and ``factory/samples`` are links to the repository's own ``fixtures/``, ``ros/`` and ``samples/`` (where users and
``colcon`` find them by path); a wheel carries them as package data (``pyproject.toml``).
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path


def shipped(folder: str) -> Path:
    """The folder ``folder`` of the ``factory`` package as a path on disk.

    Resolved, so in a checkout it names the repository's folder (``…/fixtures``), not the link.
    The CLI's path options and Alembic need real files: factory is installed unzipped (a wheel
    installed by pip or pipx, or a checkout), never imported from a zip archive.
    """
    return Path(str(importlib.resources.files("factory") / folder)).resolve()


#: The tool library and cell definitions (the repository's ``fixtures/``).
FIXTURES = shipped("fixtures")
#: factory's own ROS 2 interface packages (``factory_msgs``; the repository's ``ros/``), the one
#: source of their message definitions written into every MCAP.
ROS_INTERFACES = shipped("ros")
#: Foxglove's scene and image-annotation message definitions (``PKG/msg/NAME.msg``).
FOXGLOVE_INTERFACES = shipped("msg")
#: The sample parts and the sample orders ``factory simulate`` runs without an orders file.
SAMPLES = shipped("samples")
#: The process record's Alembic migrations (:mod:`factory.record`).
MIGRATIONS = shipped("migrations")
