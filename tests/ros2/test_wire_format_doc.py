"""docs/wire_format.md holds the tables docs/wire_format_tables.py prints from the code.

Keys, type hashes, tokens and example bytes are generated, not typed: a change of a type (its
hash), of a key or of the attachment shows here until the page is regenerated. docs/ros2.md
must give the same hashes.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs"


def load_tables() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "wire_format_tables", DOCS / "wire_format_tables.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


TABLES = load_tables()
TEXT_SECTIONS = ("subscription keys", "service tokens", "attachment")


@pytest.mark.parametrize("section", list(TABLES.SECTIONS))
def test_the_page_holds_every_generated_line(section: str) -> None:
    page = (DOCS / "wire_format.md").read_text()
    lines = TABLES.SECTIONS[section]()
    if section == "wrench":
        # the byte table: each field's offset and bytes, as the page's table shows them
        for line in lines[1:]:
            offset, hexbytes, _name = re.match(r"\s*(\d+)  (.+?)\s{2,}(.+)$", line).groups()
            assert f"| {offset} | `{hexbytes}` |" in page, line
        wrench_bytes, diagnostics_bytes = re.findall(r"(\d+) bytes", lines[0])
        assert f"\n{wrench_bytes} bytes: an estimate" in page
        assert f"For the Omni it is {diagnostics_bytes} bytes" in page
        return
    if section == "joint state":
        sizes = re.findall(r"(\d+) bytes", lines[0])
        assert f"`measured_js` payload is {sizes[0]} bytes" in page
        assert f"`setpoint_js` payload {sizes[1]}" in page
        return
    for line in lines:
        expected = f"    {line}" if section in TEXT_SECTIONS else line
        assert expected in page, line


def test_ros2_md_gives_the_same_hashes() -> None:
    ros2 = (DOCS / "ros2.md").read_text()
    hashes = set(re.findall(r"RIHS01_[0-9a-f]{64}", "\n".join(TABLES.hash_table())))
    assert len(hashes) == 5
    assert set(re.findall(r"RIHS01_[0-9a-f]{64}", ros2)) <= hashes
    for line in TABLES.hash_table()[2:]:
        ros_type, _, type_hash = (cell.strip(" `") for cell in line.strip("|").split("|"))
        assert f"| `{ros_type}` | `{type_hash}` |" in ros2, ros_type
