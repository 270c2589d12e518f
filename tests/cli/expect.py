"""What every command's failure must look like, checked one way for all CLI tests."""

from __future__ import annotations

from cli.common import STAGE_LINE


def assert_one_line_error(result, *needles: str, code: int = 1) -> None:
    """One ``error: ...`` line on stderr naming each of ``needles``, exit ``code``, nothing on stdout
    (besides the stages that ran before it, as ``factory plan`` shows them in a pipe: ``STAGE_LINE``)."""
    assert result.exit_code == code, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip() and not STAGE_LINE.match(line)]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert "Traceback" not in result.output
    assert result.stdout == ""


def simulate_exit(doc: dict) -> int:
    """The exit code ``factory simulate`` owes the run its JSON ``doc`` describes: 3 when an order
    ended failed or rejected (everything written, with findings), else 0."""
    return 3 if any(o["outcome"] != "done" for o in doc["orders"]) else 0
