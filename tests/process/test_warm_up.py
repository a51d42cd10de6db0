"""The warm-up: kernel groups compiled ahead in child processes, and the stamp that skips it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.process import warm_up
from teleop_force.process.warm_up import KERNEL_GROUPS, KernelGroup, compile_group


def test_groups_name_importable_targets() -> None:
    assert len({g.name for g in KERNEL_GROUPS}) == len(KERNEL_GROUPS)
    for group in KERNEL_GROUPS:
        module, _, function = group.target.partition(":")
        assert callable(getattr(__import__(module, fromlist=[function]), function)), group


def test_a_target_without_a_function_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="module:function"):
        KernelGroup("bad", "a bad group", "teleop_force.service.kernels")


def test_an_unknown_group_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="no kernel group 'nope'"):
        compile_group("nope")


def _isolated_cache(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    cache = tmp_path / "numba"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    return cache


def test_a_failing_group_is_reported_and_writes_no_stamp(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # A group the child process does not know: it exits with an error, which is reported.
    cache = _isolated_cache(monkeypatch, tmp_path)
    ghost = KernelGroup("ghost", "a group only this process knows", "json:dumps")
    monkeypatch.setattr(warm_up, "KERNEL_GROUPS", (ghost,))
    lines: list[str] = []
    report = warm_up.warm_up(progress=lines.append, jobs=1)
    assert not report.cached and not report.ok
    (timing,) = report.groups
    assert timing.name == "ghost" and not timing.ok and "no kernel group 'ghost'" in timing.error
    assert lines[0] == "compiling a group only this process knows, first run only (1/1)"
    assert "failed" in lines[1] and "its process will compile it" in lines[1]
    assert not warm_up.is_warm()
    assert not (cache / "teleop_force_warm_up.json").exists()


def test_the_stamp_follows_the_sources_and_the_cpu(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    _isolated_cache(monkeypatch, tmp_path)
    monkeypatch.setattr(warm_up, "KERNEL_GROUPS", ())  # nothing to compile: only the stamp
    assert not warm_up.is_warm()
    report = warm_up.warm_up()
    assert report.ok and not report.cached and warm_up.is_warm()
    assert warm_up.warm_up().cached  # the stamp matches: nothing started
    monkeypatch.setenv("NUMBA_CPU_NAME", "generic")  # another CPU: compiled afresh
    assert not warm_up.is_warm()
    monkeypatch.delenv("NUMBA_CPU_NAME")
    assert warm_up.is_warm()
    source = Path(warm_up.__file__)
    stat = source.stat()
    try:  # a source file changed (its mtime): compiled afresh
        os.utime(source, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))
        assert not warm_up.is_warm()
    finally:
        os.utime(source, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert warm_up.is_warm()


def test_the_report_summary_is_json_ready() -> None:
    report = warm_up.WarmUpReport(
        cached=False,
        seconds=1.23456,
        groups=(warm_up.GroupTiming("a", 1.0004, True), warm_up.GroupTiming("b", 2.0, False)),
    )
    assert not report.ok
    assert report.summary() == {
        "cached": False,
        "seconds": 1.235,
        "groups": {"a": {"seconds": 1.0, "ok": True}, "b": {"seconds": 2.0, "ok": False}},
    }
