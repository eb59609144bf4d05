"""The README's Python examples run, in order, and say what the README says they say."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_readme_starts_with_the_two_commands() -> None:
    first_block = re.search(r"```sh\n(.*?)```", README.read_text(), flags=re.S)
    assert first_block is not None
    commands = [line.split("#")[0].strip() for line in first_block.group(1).splitlines()]
    assert commands == ["make demo", "make test"]


def test_readme_python_examples_run() -> None:
    blocks = _python_blocks()
    assert len(blocks) >= 4
    namespace: dict[str, object] = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        for block in blocks:
            exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
    lines = out.getvalue().splitlines()
    # The coercion example: 1023 on a 0:1023 axis is 511 on a 0:511 one, 2 becomes 1.
    assert any("511" in line and "1." in line for line in lines), lines
    # "don't care" parses to the singleton; the three matchers agree; the Hough finds the pose.
    assert lines.count("True") >= 2, lines
    assert lines[-1].split() == ["8", "True"], lines
