"""Fingerprints of every output `factory plan` writes for the samples, to show a refactor changes none.

A structural change (issue 28, "The house before the next floor") must leave every output byte-identical:
G-code, setup sheets, robot programs, the plan summary without its wall times, the MCAP's message payloads
and the pictures. Record the fingerprints on the commit before the change, then check the commit after:

    .venv/bin/python benchmarks/identical_outputs.py --record before.json          # on the old commit
    .venv/bin/python benchmarks/identical_outputs.py --check before.json           # on the new one
    .venv/bin/python benchmarks/identical_outputs.py --check before.json --rounds  # two processors, rounds forced

To record an older commit without reinstalling, point PYTHONPATH at a checkout of it (a worktree):
``PYTHONPATH=/tmp/old .venv/bin/python benchmarks/identical_outputs.py --record before.json --root /tmp/old``.
Exits 1 and names every output that differs, with the MCAP channels that differ.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mcap.reader import make_reader

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("bracket", "plate_bosses", "stepped_wall", "dome_mould", "relief")
#: Summary keys that are measurements of this run, not outputs of the plan.
WALL_TIME_KEYS = ("seconds",)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _normalised_text(path: Path, folders: dict[str, str]) -> bytes:
    """A text output with the run's own folders named, so two runs in two checkouts compare."""
    data = path.read_bytes()
    for folder, name in folders.items():
        data = data.replace(folder.encode(), name.encode())
    return data


def _summary(path: Path, folders: dict[str, str]) -> str:
    doc = json.loads(_normalised_text(path, folders))
    for key in WALL_TIME_KEYS:
        doc.pop(key, None)
    return _sha(json.dumps(doc, sort_keys=True).encode())


def _mcap(path: Path) -> dict[str, str]:
    """One fingerprint per channel: its schema and every message's log time and payload, in order."""
    per_topic: dict[str, hashlib._Hash] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            h = per_topic.setdefault(channel.topic, hashlib.sha256())
            h.update((schema.name if schema else "").encode())
            h.update(message.log_time.to_bytes(8, "little"))
            h.update(message.data)
    return {topic: h.hexdigest() for topic, h in sorted(per_topic.items())}


def fingerprint(out_dir: Path, root: Path) -> dict[str, object]:
    """Every file in ``out_dir`` by name: a digest, or for an MCAP one digest per channel."""
    folders = {str(out_dir): "<OUT>", str(root): "<ROOT>"}
    out: dict[str, object] = {}
    for path in sorted(out_dir.iterdir()):
        if path.name.endswith(".plan.json"):
            out[path.name] = _summary(path, folders)
        elif path.suffix == ".mcap":
            out[path.name] = _mcap(path)
        elif path.suffix == ".png":
            out[path.name] = _sha(path.read_bytes())
        else:
            out[path.name] = _sha(_normalised_text(path, folders))
    return out


#: ``--rounds``: the plan's process with a round of verify ahead begun at every offer and each waited for (as on
#: a machine with an idle processor, however loaded this one is), on two processors: the pictures and the log drawn
#: in their process, the last round's program and moves taken by the post and verify.
FORCED_ROUNDS = ("import factory.verify as v; v.IdleMeter.idle = lambda self, own=0.0: 2.0; v.OVERTAKE_BELOW = 0.0; "
                 "from cli.main import main; main()")


def plan(part: str, root: Path, work: Path, rounds: bool = False) -> dict[str, object]:
    out_dir = work / part
    code = FORCED_ROUNDS if rounds else "from cli.main import main; main()"
    cmd = [sys.executable, "-c", code, "plan", str(root / "samples" / f"{part}.stl"), "-o", str(out_dir), "--quiet"]
    env = dict(os.environ, FACTORY_THREADS="2" if rounds else "1")
    done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    if done.returncode not in (0, 3):
        raise SystemExit(f"error: {part}: factory plan exited {done.returncode}: {done.stderr.strip()[-400:]}")
    return fingerprint(out_dir, root)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--record", type=Path, help="write the fingerprints to this JSON file")
    mode.add_argument("--check", type=Path, help="compare against fingerprints recorded earlier")
    ap.add_argument("--root", type=Path, default=ROOT, help="the checkout whose samples are planned")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rounds", action="store_true",
                    help="plan on two processors with every round of verify ahead forced (FORCED_ROUNDS); default: one")
    ap.add_argument("--parts", default=",".join(PARTS), help="comma-separated samples (default: all five)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="identical-") as tmp, ThreadPoolExecutor(args.jobs) as pool:
        parts = tuple(args.parts.split(","))
        prints = dict(zip(parts, pool.map(lambda p: plan(p, args.root, Path(tmp), args.rounds), parts)))
    if args.record:
        args.record.write_text(json.dumps(prints, indent=1, sort_keys=True) + "\n")
        print(f"recorded {sum(len(v) for v in prints.values())} outputs of {len(parts)} parts in {args.record}")
        return 0
    before = json.loads(args.check.read_text())
    differ = []
    for part in parts:
        old, new = before.get(part, {}), prints[part]
        for name in sorted(set(old) | set(new)):
            if old.get(name) == new.get(name):
                continue
            if isinstance(old.get(name), dict) and isinstance(new.get(name), dict):
                topics = sorted(t for t in set(old[name]) | set(new[name]) if old[name].get(t) != new[name].get(t))
                differ.append(f"{part}: {name}: channels {', '.join(topics)}")
            else:
                differ.append(f"{part}: {name}" + ("" if name in old and name in new else " (missing on one side)"))
    for line in differ:
        print(f"differs: {line}")
    total = sum(len(v) for v in prints.values())
    print(f"{total - len(differ)} of {total} outputs identical" if differ else f"all {total} outputs identical")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
