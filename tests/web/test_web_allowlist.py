import os

import pytest

from web.allowlist import (
    PROJECT_ROOT,
    Allowlist,
    PathNotAllowedError,
    model_allowlist,
    recording_allowlist,
)


@pytest.fixture
def tree(tmp_path):
    allowed = tmp_path / "models"
    (allowed / "sub").mkdir(parents=True)
    (allowed / "a.json").write_text("{}")
    (allowed / "sub" / "b.json").write_text("{}")
    (allowed / "notes.txt").write_text("x")
    outside = tmp_path / "secret"
    outside.mkdir()
    (outside / "s.json").write_text("{}")
    os.symlink(outside / "s.json", allowed / "link_out.json")
    os.symlink(allowed / "a.json", allowed / "link_in.json")
    return tmp_path, Allowlist.of([allowed], (".json",))


def test_resolves_files_inside_the_folders(tree):
    root, allow = tree
    assert allow.resolve(root / "models" / "a.json") == (root / "models" / "a.json").resolve()
    assert allow.resolve(str(root / "models" / "sub" / "b.json")).name == "b.json"
    assert allow.resolve(root / "models" / "link_in.json").name == "a.json"


@pytest.mark.parametrize(
    "relative",
    [
        "secret/s.json",  # outside
        "models/../secret/s.json",  # traversal
        "models/link_out.json",  # symlink escaping the folder
        "models/notes.txt",  # wrong suffix
        "models/missing.json",  # no such file
        "models/sub",  # a folder
    ],
)
def test_rejects_everything_else(tree, relative):
    root, allow = tree
    with pytest.raises(PathNotAllowedError):
        allow.resolve(root / relative)


def test_rejects_odd_strings(tree):
    _, allow = tree
    for bad in ("", "a\x00b.json", "/etc/passwd", "~/.ssh/id_rsa.json"):
        with pytest.raises(PathNotAllowedError):
            allow.resolve(bad)


def test_lists_only_allowed_files_with_short_labels(tree):
    root, allow = tree
    names = sorted(p.name for p in allow.list_files())
    assert names == ["a.json", "b.json"]  # link_in resolves to a.json, link_out is outside
    assert allow.contains(root / "models" / "x.json")
    assert not allow.contains(root / "secret" / "x.json")
    assert allow.label((root / "models" / "sub" / "b.json").resolve()) == os.path.join(
        "sub", "b.json"
    )


def test_missing_folders_list_nothing(tmp_path):
    assert Allowlist.of([tmp_path / "nope"], (".json",)).list_files() == []


def test_project_allowlists(tmp_path):
    models = model_allowlist([tmp_path])
    assert PROJECT_ROOT / "recordings" in models.folders
    assert PROJECT_ROOT / "teleop_force" / "models" in models.folders
    assert tmp_path.resolve() in models.folders
    recordings = recording_allowlist()
    assert recordings.folders == (PROJECT_ROOT / "recordings",)
    assert recordings.suffixes == (".mcap",)  # what teleop-force replay plays
