"""Where the data that ships with factory lives (tool library, default cell)."""

from __future__ import annotations

from pathlib import Path

#: The project's ``fixtures/`` folder: tool library and cell definitions.
FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
#: The project's ``ros/`` folder: factory's own ROS 2 interface packages (``factory_msgs``), the
#: one source of the message definitions written into every MCAP.
ROS_INTERFACES = Path(__file__).resolve().parents[2] / "ros"
