"""Generated blocks of Markdown files: the text between ``<!-- report:NAME -->`` and
``<!-- /report:NAME -->`` lines, which `mjx-emp report --into` writes and the tests read back
to check that every figure in the docs is what its command makes of the committed rows."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mjx_emp.errors import ConfigError
from mjx_emp.run.store import replace_file


def block_markers(name: str) -> tuple[str, str]:
    """The lines that open and close a generated block ``name`` in a Markdown file."""
    return f"<!-- report:{name} -->", f"<!-- /report:{name} -->"


def block_span(lines: Sequence[str], name: str, markdown_file: Path) -> tuple[int, int]:
    """Indices of the opening and closing marker lines of block ``name``; missing, repeated or
    misordered markers are a ConfigError naming the file and the two lines to add."""
    opening, closing = block_markers(name)
    starts = [i for i, line in enumerate(lines) if line.strip() == opening]
    ends = [i for i, line in enumerate(lines) if line.strip() == closing]
    if len(starts) != 1 or len(ends) != 1 or starts[0] > ends[0]:
        found = f"found {len(starts)} opening and {len(ends)} closing marker lines"
        raise ConfigError(f"block: {markdown_file} needs exactly one block {name!r}, the lines {opening} and "
                          f"{closing} on their own, in that order ({found}); add them where the text belongs")
    return starts[0], ends[0]


def read_text(path: Path, what: str) -> str:
    """A file's text; a missing file is a ConfigError saying ``what`` it was to be."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{what}: {path} does not exist") from None


def read_block(markdown_file: Path | str, name: str) -> str:
    """The text between block ``name``'s marker lines (without the final newline)."""
    path = Path(markdown_file)
    lines = read_text(path, "block").splitlines(keepends=True)
    start, end = block_span(lines, name, path)
    return "".join(lines[start + 1:end]).removesuffix("\n")


def with_block(text: str, name: str, content: str, markdown_file: Path) -> str:
    """``text`` with block ``name``'s content replaced by ``content`` plus a newline (no blank
    line for empty content); the marker lines and all outside them are kept byte for byte."""
    lines = text.splitlines(keepends=True)
    start, end = block_span(lines, name, markdown_file)
    if not lines[start].endswith("\n"):
        lines[start] += "\n"
    body = content if not content or content.endswith("\n") else content + "\n"
    return "".join(lines[:start + 1]) + body + "".join(lines[end:])


def write_block(markdown_file: Path | str, name: str, text: str) -> bool:
    """Put ``text`` between block ``name``'s marker lines of ``markdown_file``, atomically;
    True where the file changed (an unchanged block leaves the file untouched)."""
    path = Path(markdown_file)
    old = read_text(path, "into")  # the file `report --into` names
    new = with_block(old, name, text, path)
    if new == old:
        return False
    replace_file(path, new, chosen=True, field="into")
    return True
