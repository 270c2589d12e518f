"""Decode MCAP files with the Foxglove app's own parsers (Node.js), from Python tests.

Also: compare the ``foxglove_msgs`` definitions factory ships with Foxglove's own, and validate
every model embedded in a ``SceneUpdate`` with the Khronos glTF validator.

The app opens an MCAP with ``@mcap/core``, parses every ``ros2msg`` schema with
``@foxglove/rosmsg`` and reads every CDR message with ``@foxglove/rosmsg2-serialization``;
``tests/foxglove/decode.mjs`` does the same with the versions pinned in
``tests/foxglove/package-lock.json``. The npm packages are installed there with ``npm ci`` the
first time a test needs them (``node`` and ``npm`` from Debian's packages; ``.ci/run`` installs
them on a fresh machine).
"""

from __future__ import annotations

import functools
import json
import shutil
import subprocess
from pathlib import Path

PROJECT = Path(__file__).resolve().parent / "foxglove"
SCRIPT = PROJECT / "decode.mjs"
SCHEMAS_SCRIPT = PROJECT / "schemas.mjs"


@functools.cache
def _installed() -> Path:
    """The ``node`` executable, after ``npm ci`` in :data:`PROJECT` if its packages are missing."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        raise AssertionError("node and npm are needed to check MCAP files with Foxglove's parsers "
                             "(Debian: apt-get install nodejs npm)")
    if not (PROJECT / "node_modules" / "@foxglove" / "rosmsg").is_dir():
        done = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=PROJECT, capture_output=True,
                              text=True, timeout=600)
        if done.returncode != 0:
            raise AssertionError(f"npm ci in {PROJECT} failed:\n{done.stderr}")
    return Path(node)


def foxglove_decode(*paths: str | Path) -> dict[str, dict]:
    """What the Foxglove parsers made of each file, keyed by the file's path as given.

    Returns
    -------
    dict
        ``{path: {"schemas": {name: {"ok": bool, "error"?: str}},
        "topics": {topic: {"schema": name, "decoded": n, "failed": n, "error"?: str}}}}``.
        Failures are reported here, not raised; see :func:`check_foxglove_decodes`.
    """
    node = _installed()
    done = subprocess.run([str(node), str(SCRIPT), *map(str, paths)], capture_output=True, text=True,
                          timeout=600)
    if done.returncode not in (0, 1):
        raise AssertionError(f"decode.mjs failed (exit {done.returncode}):\n{done.stderr}")
    return json.loads(done.stdout)


def check_foxglove_decodes(path: str | Path) -> dict[str, int]:
    """Assert that Foxglove parses every schema and decodes every message of ``path``.

    Returns
    -------
    dict of str to int
        Topic -> number of messages decoded.

    Raises
    ------
    AssertionError
        Naming the file and each schema or topic that failed, with the parser's error.
    """
    report = foxglove_decode(path)[str(path)]
    problems = [f"schema {name}: {s['error']}" for name, s in report["schemas"].items() if not s["ok"]]
    problems += [f"topic {topic} ({t['schema']}): {t['failed']} message(s) failed: {t.get('error')}"
                 for topic, t in report["topics"].items() if t["failed"]]
    if problems:
        raise AssertionError(f"{path}: Foxglove cannot decode it:\n  " + "\n  ".join(problems))
    return {topic: t["decoded"] for topic, t in report["topics"].items() if t["decoded"]}


def foxglove_schema_differences(msg_dir: str | Path) -> dict[str, str | None]:
    """Each ``NAME.msg`` in ``msg_dir`` compared with Foxglove's own ROS 2 definition of ``NAME``
    (``@foxglove/schemas``): ``None`` when the fields and constants agree, else what differs."""
    node = _installed()
    done = subprocess.run([str(node), str(SCHEMAS_SCRIPT), str(msg_dir)], capture_output=True, text=True,
                          timeout=120)
    if done.returncode not in (0, 1):
        raise AssertionError(f"schemas.mjs failed (exit {done.returncode}):\n{done.stderr}")
    return json.loads(done.stdout)
