"""The teleop-force browser dashboard (viser): ``python -m web --device slave --port 8080``.

A ROS 2 node on rmw_zenoh's keys (:data:`web.telemetry.NODE_NAME`): it subscribes to the
slave's and the master's topics (:mod:`teleop_force.ros2.topics`, :mod:`web.telemetry`) and
the service's residual watch (:mod:`web.residual_view`), and talks to the service over the
project's JSON keys (:mod:`web.control`), so it works against the real system, a replay, or
synthetic messages.

Threads: Zenoh's callbacks append into ring buffers (:mod:`web.telemetry`); one render thread
updates the banner, the 3D scene and the uPlot charts at ``--plot-hz`` (30) and Fig. 4 at
``--fig-hz`` (4); one service thread polls the service statistics (1 Hz) and model (every
10 s, and after a load); GUI callbacks run on viser's worker threads.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import viser
import zenoh

from teleop_force.errors import TeleopForceError
from teleop_force.process.memory import MemoryTrimmer
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.node import Node
from teleop_force.transport import keys
from teleop_force.transport.session import (
    ZenohOptions,
    add_zenoh_arguments,
    open_session,
    options_from_args,
)
from web.allowlist import Allowlist, PathNotAllowedError, model_allowlist, recording_allowlist
from web.buffers import bin_mean
from web.control import (
    MIN_SPEED,
    ReplayProcess,
    ServiceClient,
    adaptation_request,
    control_key,
    recording_name,
    replay_command,
    stats_adaptation,
    stats_model_path,
    stats_recording,
    zenoh_cli_args,
)
from web.coverage_data import CoverageInfo, coverage_from_model, finite_or, unwrap_model
from web.coverage_view import Background, compose_frame, render_background
from web.plots import LivePlots, newest_time, plot_frames
from web.residual_view import DiagnosticsInbox, diagnostics_markdown
from web.scene import OmniScene
from web.stats import LATENCY_NOTE, StreamSnapshot
from web.status import UNTRAINED_HOLD_S, TrustInputs, assess, banner_html
from web.telemetry import (
    FE_COVERAGE,
    FE_F,
    FE_TRAINED,
    JS_Q,
    JS_QD,
    NODE_NAME,
    STREAMS,
    Subscriptions,
    Telemetry,
)

DEFAULT_PORT: Final = 8080
DEFAULT_TISSUE_Y_M: Final = -0.11
NONE_OPTION: Final = "(none found)"


@dataclass(frozen=True)
class DashboardConfig:
    """Settings of one dashboard (the command-line flags)."""

    device: str = "slave"
    master_device: str = "master"
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    window_s: float = 10.0
    plot_hz: float = 30.0
    fig_hz: float = 4.0
    n_bins: int = 300
    trail_s: float = 3.0
    tissue_y_m: float = DEFAULT_TISSUE_Y_M
    stale_after_s: float = 0.25
    models_dirs: tuple[Path, ...] = ()
    zenoh: ZenohOptions = field(default_factory=ZenohOptions)

    def __post_init__(self) -> None:
        """Validate ids and rates."""
        keys.validate_chunk(self.device)
        keys.validate_chunk(self.master_device, "master device id")
        topics.validate_device(self.device)  # also a ROS 2 name token: /<device>/...
        topics.validate_device(self.master_device)
        if not (0.5 <= self.plot_hz <= 120 and 0.2 <= self.fig_hz <= 30):
            raise TeleopForceError("plot-hz must be in [0.5, 120] and fig-hz in [0.2, 30]")
        if not (1.0 <= self.window_s <= 60.0 and 0.2 <= self.trail_s <= self.window_s):
            raise TeleopForceError("window must be 1..60 s and the trail 0.2 s..window")
        if not 20 <= self.n_bins <= 2000:
            raise TeleopForceError("bins must be in [20, 2000]")


class _Periodic:
    """Calls a function every ``period_s`` (perf_counter) when :meth:`due` says so."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._next = 0.0

    def due(self, now: float) -> bool:
        if now < self._next:
            return False
        self._next = now + self.period_s
        return True

    def trigger(self) -> None:
        self._next = 0.0


class Dashboard:
    """The viser server, its GUI, and the threads that keep it current."""

    def __init__(self, config: DashboardConfig, session: zenoh.Session) -> None:
        """Create the server and GUI (nothing is subscribed until :meth:`start`)."""
        self.config = config
        self._session = session
        self.telemetry = Telemetry()
        self.service = ServiceClient(session, config.device)
        self.models = model_allowlist(config.models_dirs)
        self.recordings = recording_allowlist()
        self.replay = ReplayProcess()
        self.diagnostics = DiagnosticsInbox()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._node: Node | None = None
        self._subs: Subscriptions | None = None
        self._model_labels: dict[str, Path] = {}
        self._recording_labels: dict[str, Path] = {}
        self._coverage = coverage_from_model(None)
        self._background: Background | None = None
        self._fig4_shown: Background | None = None
        self._model_key = ""
        self._model_refresh = _Periodic(10.0)
        self._service_stats: Mapping[str, Any] | None = None
        self._service_note = "service: no reply yet"
        self._tissue_source = "flag"
        self._model: Mapping[str, Any] | None = None
        self._banner = ""
        self._panel_label = ""
        self.server = viser.ViserServer(host=config.host, port=config.port, label="teleop-force")
        self._build_gui()

    # -- GUI ---------------------------------------------------------------------------

    def _build_gui(self) -> None:
        server, gui, cfg = self.server, self.server.gui, self.config
        gui.configure_theme(control_width="large", show_share_button=False, show_logo=False)
        gui.set_panel_label(f"teleop-force: {cfg.device}")
        self.scene = OmniScene(server, cfg.tissue_y_m)
        self.banner = gui.add_html(banner_html(assess(TrustInputs())))
        with gui.add_folder("Fig. 4: training coverage (qd2-qd3, qd1)"):
            self._background = render_background(self._coverage)
            self.fig4 = gui.add_image(self._background.image, format="jpeg", jpeg_quality=85)
            self.fig4_note = gui.add_markdown(
                "Green: where the friction network was trained. Trajectory of the last "
                f"{cfg.trail_s:g} s: blue on trained ground, red off it, grey unknown."
            )
        with gui.add_folder("Controls"):
            self._build_controls(gui)
        with gui.add_folder("Residual watch"):
            self.watch_md = gui.add_markdown(diagnostics_markdown(None))
        with gui.add_folder("Statistics"):
            self.stats_md = gui.add_markdown("waiting for data")
        gui.main_panel.dock_right()
        gui.main_panel.set_width(440)

        panel = gui.add_panel()
        with panel.add_tab("Live plots"):
            self.plots = LivePlots(gui, cfg.window_s, cfg.n_bins)
        panel.dock_left()
        panel.set_width(520)

    def _build_controls(self, gui: viser.GuiApi) -> None:
        gui.add_markdown("**Model** (from recordings/, teleop_force/models/, --models-dir)")
        self.model_dropdown = gui.add_dropdown("Model file", (NONE_OPTION,))
        load = gui.add_button("Load model into the service")
        refresh = gui.add_button("Refresh file lists")
        self.model_status = gui.add_markdown(" ")
        load.on_click(lambda _: self._load_model())
        refresh.on_click(lambda _: self._refresh_file_lists())

        gui.add_markdown("**Recording** (into recordings/)")
        self.record_name = gui.add_text("Name", initial_value="")
        rec_group = gui.add_button_group("Recording", ("Start", "Stop"))
        self.record_status = gui.add_markdown(" ")
        rec_group.on_click(lambda event: self._record(event.target.value == "Start"))

        gui.add_markdown("**Replay** (recordings/ only)")
        self.replay_dropdown = gui.add_dropdown("Recording", (NONE_OPTION,))
        self.replay_speed = gui.add_slider(
            "Speed", min=MIN_SPEED, max=4.0, step=0.05, initial_value=1.0
        )
        replay_group = gui.add_button_group("Replay", ("Play", "Stop"))
        self.replay_status = gui.add_markdown("idle")
        replay_group.on_click(lambda event: self._replay(event.target.value == "Play"))

        gui.add_markdown("**Estimator**")
        self.adaptation = gui.add_checkbox("Online adaptation", initial_value=False)
        self.adaptation_status = gui.add_markdown(" ")
        self.adaptation.on_update(lambda _: self._set_adaptation())

        gui.add_markdown("**Display**")
        show_true = gui.add_checkbox("Show true force", initial_value=True)
        show_ghost = gui.add_checkbox("Show master ghost", initial_value=True)
        show_true.on_update(lambda _: setattr(self.scene, "show_true_force", show_true.value))
        show_ghost.on_update(lambda _: setattr(self.scene, "show_ghost", show_ghost.value))
        adapt_key, _ = adaptation_request(self.config.device, True)
        record_key = control_key(self.config.device)
        gui.add_markdown(
            f"Keys: adaptation `{adapt_key}` (on/off), recording `{record_key}`;"
            f" tissue plane at y = {self.config.tissue_y_m:+.3f} m unless the service reports one."
        )
        self._refresh_file_lists()

    def _refresh_file_lists(self) -> None:
        self._model_labels = _labelled(self.models)
        self._recording_labels = _labelled(self.recordings)
        _set_options(self.model_dropdown, list(self._model_labels))
        _set_options(self.replay_dropdown, list(self._recording_labels))

    def _chosen(self, labels: Mapping[str, Path], choice: str, allowlist: Allowlist) -> Path:
        path = labels.get(choice)
        if path is None:
            raise PathNotAllowedError("choose a file from the list")
        return allowlist.resolve(path)  # checked again: the file may have changed since listed

    def _wait_for_stats(
        self, done: Callable[[Mapping[str, Any]], bool], timeout_s: float = 3.0
    ) -> tuple[bool, Mapping[str, Any] | None]:
        """Poll the service statistics until ``done(stats)`` or the timeout."""
        deadline = time.perf_counter() + timeout_s
        stats: Mapping[str, Any] | None = None
        while True:
            reply = self.service.fetch_stats(timeout_s=1.0)
            if reply.ok and isinstance(reply.data, Mapping):
                stats = reply.data
                self._service_stats = stats
                if done(stats):
                    return True, stats
            if time.perf_counter() > deadline:
                return False, stats
            time.sleep(0.3)

    def _load_model(self) -> None:
        try:
            path = self._chosen(self._model_labels, self.model_dropdown.value, self.models)
        except PathNotAllowedError as exc:
            self.model_status.content = f"**not loaded:** {exc}"
            return
        self.model_status.content = f"asking the service to load `{path.name}`..."
        reply = self.service.request_model_load(path)
        if not reply.ok:
            self.model_status.content = f"**load failed:** {reply.text}"
            return
        loaded, stats = self._wait_for_stats(lambda st: stats_model_path(st) == path)
        if loaded:
            self.model_status.content = f"the service now runs `{path.name}`"
        else:
            running = stats_model_path(stats)
            name = running.name if running is not None else "an unknown model"
            self.model_status.content = (
                f"**not loaded:** the service still runs `{name}` (it does not load models "
                "at run time yet; restart it with --model)"
            )
        self._model_refresh.trigger()

    def _record(self, start: bool) -> None:
        if not start:
            reply = self.service.set_recording(False)
        else:
            try:
                name = recording_name(self.record_name.value)
            except TeleopForceError as exc:
                self.record_status.content = f"**{exc}**"
                return
            target = self.recordings.folders[0] / name
            if not self.recordings.contains(target) or target.exists():
                self.record_status.content = f"**{name} exists or is not allowed**"
                return
            reply = self.service.set_recording(True, target)
        if reply.ok:
            _, stats = self._wait_for_stats(lambda st: False, timeout_s=0.0)
            self.record_status.content = f"service: {stats_recording(stats)}"
        elif reply.text.startswith("no reply") and self._service_stats is not None:
            self.record_status.content = (
                "**the service does not take recording commands**: it records only when "
                f"started with --record PATH (now: {stats_recording(self._service_stats)})"
            )
        else:
            self.record_status.content = f"**{reply.text}**"

    def _replay(self, play: bool) -> None:
        if not play:
            self.replay_status.content = self.replay.stop()
            return
        try:
            path = self._chosen(self._recording_labels, self.replay_dropdown.value, self.recordings)
            speed = float(self.replay_speed.value)
            command = replay_command(path, speed, zenoh_cli_args(self.config.zenoh))
        except TeleopForceError as exc:
            self.replay_status.content = f"**{exc}**"
            return
        self.replay_status.content = self.replay.start(command, f"{path.name} at x{speed:g}")

    def _set_adaptation(self) -> None:
        enabled = bool(self.adaptation.value)
        word = "on" if enabled else "off"
        reply = self.service.set_adaptation(enabled)
        if not reply.ok:
            self.adaptation_status.content = f"**adaptation {word} failed:** {reply.text}"
            return
        confirmed, stats = self._wait_for_stats(lambda st: stats_adaptation(st)[0] is enabled)
        if confirmed:
            self.adaptation_status.content = f"adaptation {word} (confirmed by the service)"
        else:
            state, note = stats_adaptation(stats)
            now = "unknown" if state is None else ("on" if state else "off")
            self.adaptation_status.content = f"**the service reports adaptation {now}**" + (
                f": {note}" if note else ""
            )

    # -- lifecycle ---------------------------------------------------------------------

    def start(self) -> None:
        """Declare the ROS 2 node, subscribe and start the render and service threads."""
        cfg = self.config
        codec.warm_up()  # rosbags compiles each type on first use: not on the first sample
        self._node = Node(self._session, NODE_NAME)
        self._subs = Subscriptions(self._node, self.telemetry, cfg.device, cfg.master_device)
        self.diagnostics.subscribe(self._node, cfg.device)
        for target, name in ((self._render_loop, "render"), (self._service_loop, "service")):
            thread = threading.Thread(target=target, daemon=True, name=f"dashboard-{name}")
            thread.start()
            self._threads.append(thread)

    def stop(self) -> None:
        """Stop the threads, undeclare the subscribers, stop a replay and the server."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)
        if self._subs is not None:
            self._subs.close()
        self.diagnostics.close()
        if self._node is not None:
            self._node.close()
        self.replay.stop()
        self.server.stop()

    def request_stop(self) -> None:
        """Make :meth:`wait` return (safe from a signal handler)."""
        self._stop.set()

    def wait(self) -> None:
        """Block until :meth:`stop` is called (from a signal handler or another thread)."""
        while not self._stop.wait(0.5):
            pass

    # -- service thread ----------------------------------------------------------------

    def _service_loop(self) -> None:
        stats_timer = _Periodic(1.0)
        while not self._stop.wait(0.1):
            now = time.perf_counter()
            if stats_timer.due(now):
                reply = self.service.fetch_stats(timeout_s=0.8)
                if reply.ok and isinstance(reply.data, Mapping):
                    self._service_stats = reply.data
                    self._service_note = "service: stats ok"
                else:
                    self._service_note = f"service stats: {reply.text}"
                self._update_tissue()
            if self._model_refresh.due(now):
                reply = self.service.fetch_model(timeout_s=2.0)
                model = unwrap_model(reply.data) if reply.ok else None
                if model is not None:
                    self._set_model(model)
                elif self._model_key == "":  # say why there is no coverage to show
                    note = reply.text if not reply.ok else "the reply is not a model"
                    message = f"model: {note}"
                    if message != self._coverage.message:
                        self._coverage = CoverageInfo("none", None, None, message)
                        self._background = render_background(self._coverage)

    def _set_model(self, model: Mapping[str, Any]) -> None:
        key = _picture_key(model)
        if key == self._model_key:
            return
        coverage = coverage_from_model(model)
        self._background = render_background(coverage, key)  # swapped in one assignment
        self._coverage = coverage
        self._model_key = key
        self._model = model
        self._update_tissue()

    def _update_tissue(self) -> None:
        height, source = self.config.tissue_y_m, "flag"
        model = self._model
        notes = model.get("notes") if model is not None else None
        for candidate, name in ((notes, "model notes"), (self._service_stats, "service stats")):
            if isinstance(candidate, Mapping) and "tissue_y_m" in candidate:
                value = finite_or(candidate["tissue_y_m"], math.nan)
                if math.isfinite(value) and abs(value) < 1.0:
                    height, source = value, name
        self._tissue_source = source
        self.scene.set_tissue_height(height)

    # -- render thread -----------------------------------------------------------------

    def _render_loop(self) -> None:
        period = 1.0 / self.config.plot_hz
        fig_timer = _Periodic(1.0 / self.config.fig_hz)
        stats_timer = _Periodic(0.5)
        next_frame = time.perf_counter()
        while not self._stop.is_set():
            now = time.perf_counter()
            if now < next_frame:
                self._stop.wait(next_frame - now)
                continue
            next_frame = max(next_frame + period, now)
            try:
                self._render_frame(now, fig_timer, stats_timer)
            except Exception as exc:
                print(f"dashboard: render error: {exc!r}", file=sys.stderr)

    def _render_frame(self, now: float, fig_timer: _Periodic, stats_timer: _Periodic) -> None:
        self._render_banner()
        if not self.server.get_clients():
            return  # nobody watching: skip the heavy parts
        tel = self.telemetry
        js = tel.joint_state.latest()
        sp = tel.setpoint.latest()
        fe = tel.estimate.latest()
        cf = tel.contact.latest()
        true_force = None
        if cf is not None and tel.stats["true_cf"].snapshot(now).age_s < 0.5:
            true_force = cf[1]
        self.scene.update(
            None if js is None else js[1][JS_Q],
            None if sp is None else sp[1],
            None if fe is None or tel.estimate_age_s() > 0.5 else fe[1][FE_F],
            true_force,
        )
        self.plots.update(plot_frames(tel, self.config.window_s, self.config.n_bins))
        if fig_timer.due(now):
            self._render_fig4()
        if stats_timer.due(now):
            self.stats_md.content = self._stats_markdown()
            inbox = self.diagnostics
            watch = diagnostics_markdown(inbox.latest, inbox.age_s())
            if watch != self.watch_md.content:
                self.watch_md.content = watch

    def _render_banner(self) -> None:
        tel = self.telemetry
        fe = tel.estimate.latest()
        status = tel.status()
        inputs = TrustInputs(
            estimate_age_s=tel.estimate_age_s(),
            untrained_joints=tel.untrained_joints(UNTRAINED_HOLD_S),
            force_nan=fe is not None and bool(np.any(np.isnan(fe[1][FE_F]))),
            coverage_weight=() if fe is None else tuple(float(w) for w in fe[1][FE_COVERAGE]),
            status_state=None if status is None else status.state,
            status_reason="" if status is None else status.reason,
            status_age_s=tel.status_age_s(),
            joint_state_age_s=tel.joint_state_age_s(),
        )
        verdict = assess(inputs, self.config.stale_after_s)
        content = banner_html(verdict)
        if content != self._banner:
            self._banner = content
            self.banner.content = content
            label = f"{self.config.device}: {verdict.short}"
            if label != self._panel_label:  # the panel title stays visible when scrolled
                self._panel_label = label
                self.server.gui.set_panel_label(label)
            self.scene.set_verdict(verdict.short, verdict.trustworthy)

    def _render_fig4(self) -> None:
        background = self._background
        if background is None:
            return
        frame = self._fig4_frame(background)
        if frame is None:  # no trajectory: show the bare figure once per background
            if self._fig4_shown is background:
                return
            frame = background.image
        self._fig4_shown = background
        self.fig4.image = frame

    def _fig4_frame(self, background: Background) -> np.ndarray | None:
        tel = self.telemetry
        t_end = newest_time(tel)
        if t_end is None:
            return None
        t_start = t_end - self.config.trail_s
        n = max(20, int(self.config.trail_s * 100))
        js = tel.joint_state.window(t_start)
        if len(js) == 0:
            return None
        t, qd = bin_mean(js.t_s, js.values[:, JS_QD], t_start, t_end + 1e-9, n)
        _, flags = bin_mean(*_estimate_flags(tel, t_start), t_start, t_end + 1e-9, n)
        keep = np.all(np.isfinite(qd), axis=1)
        if not np.any(keep):
            return None
        trained_plane = np.where(np.isnan(flags[:, 1]), np.nan, np.fmin(flags[:, 1], flags[:, 2]))
        age = (t_end - t) / self.config.trail_s
        return compose_frame(
            background, qd[keep], trained_plane[keep] >= 0.5, age[keep],
            known=np.isfinite(trained_plane[keep]),
            trained_line=flags[keep, 0] >= 0.5,
        )  # fmt: skip

    def _stats_markdown(self) -> str:
        subs = self._subs
        snaps = self.telemetry.snapshots() if subs is None else subs.snapshots()
        rows = [
            "| stream | rate Hz | latency ms (mean/max) | lost | bad | age s |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        rows += [_stats_row(name, snaps[name]) for name in STREAMS]
        lines = ["\n".join(rows), "", f"_{LATENCY_NOTE}_", ""]
        lines.append(f"Estimate age: {_age(self.telemetry.estimate_age_s())} s; "
                     f"tissue y = {self.scene.tissue_y_m:+.3f} m ({self._tissue_source}); "
                     f"replay: {self.replay.status()}")  # fmt: skip
        lines.append("")
        lines.append(f"**{self._service_note}**")
        stats = self._service_stats
        if stats:
            running = stats_model_path(stats)
            state, _ = stats_adaptation(stats)
            lines.append("")
            lines.append(
                f"Service model: `{running.name if running else '?'}`; adaptation: "
                f"{'?' if state is None else ('on' if state else 'off')}; "
                f"{stats_recording(stats)}"
            )
        if self._service_stats:
            flat = _flatten(self._service_stats)
            lines.append("")
            lines.append("| service stat | value |")
            lines.append("|---|---:|")
            lines += [f"| {k} | {v} |" for k, v in list(flat.items())[:40]]
        return "\n".join(lines)


def _picture_key(model: Mapping[str, Any]) -> str:
    """Return what Fig. 4's background depends on: coverage and active sets, not coefficients.

    Online adaptation changes coefficients all the time; redrawing only when this key changes
    keeps matplotlib off the hot path.
    """
    friction = model.get("friction")
    if not isinstance(friction, Mapping):
        return json.dumps(None)
    joints = friction.get("joints") or []
    active = [j.get("active") for j in joints if isinstance(j, Mapping)]
    picture = {"kind": friction.get("kind"), "coverage": friction.get("coverage"), "active": active}
    return json.dumps(picture, sort_keys=True, default=str)


def _estimate_flags(tel: Telemetry, t_start: float) -> tuple[np.ndarray, np.ndarray]:
    window = tel.estimate.window(t_start)
    return window.t_s, window.values[:, FE_TRAINED]


def _labelled(allowlist: Allowlist) -> dict[str, Path]:
    return {allowlist.label(path): path for path in allowlist.list_files()}


def _set_options(dropdown: viser.GuiDropdownHandle[str], labels: list[str]) -> None:
    dropdown.options = tuple(labels) or (NONE_OPTION,)  # keeps the value if still listed


def _age(value: float) -> str:
    return "never" if math.isinf(value) else f"{value:.2f}"


def _fmt(value: float, digits: int = 1) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}f}"


def _stats_row(name: str, s: StreamSnapshot) -> str:
    lost = f"{s.lost}" + (f" (+{s.restarts} restarts)" if s.restarts else "")
    return (
        f"| {name} | {_fmt(s.rate_hz, 0)} | {_fmt(s.latency_ms_mean, 2)} / "
        f"{_fmt(s.latency_ms_max, 2)} | {lost} | {s.malformed} | {_age(s.age_s)} |"
    )


def _flatten(data: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, f"{name}."))
        elif isinstance(value, float):
            out[name] = f"{value:.4g}"
        elif isinstance(value, list | tuple):
            out[name] = ", ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in value)[
                :80
            ]
        else:
            out[name] = str(value)[:80]
    return out


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser of ``python -m web``."""
    parser = argparse.ArgumentParser(
        prog="python -m web", description="teleop-force browser dashboard (viser)"
    )
    parser.add_argument("--device", default="slave", help="slave device id (default slave)")
    parser.add_argument("--master-device", default="master", help="master device id")
    parser.add_argument(
        "--host", default="127.0.0.1",
        help="address the web server binds (default 127.0.0.1; 0.0.0.0 exposes it)",
    )  # fmt: skip
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="web server port")
    parser.add_argument(
        "--tissue-y", type=float, default=DEFAULT_TISSUE_Y_M,
        help="tissue surface height y in the base frame [m] (default -0.11), unless the "
        "service reports tissue_y_m in its stats or model notes",
    )  # fmt: skip
    parser.add_argument(
        "--models-dir", action="append", default=[], metavar="DIR",
        help="extra folder of model files offered for loading (repeatable)",
    )  # fmt: skip
    parser.add_argument("--window", type=float, default=10.0, help="plot window [s]")
    parser.add_argument("--plot-hz", type=float, default=30.0, help="plot refresh rate")
    parser.add_argument("--fig-hz", type=float, default=4.0, help="Fig. 4 refresh rate")
    parser.add_argument("--trail", type=float, default=3.0, help="Fig. 4 trajectory length [s]")
    add_zenoh_arguments(parser)
    return parser


def config_from_args(args: argparse.Namespace) -> DashboardConfig:
    """Build the configuration from parsed flags."""
    return DashboardConfig(
        device=args.device,
        master_device=args.master_device,
        host=args.host,
        port=args.port,
        window_s=args.window,
        plot_hz=args.plot_hz,
        fig_hz=args.fig_hz,
        trail_s=args.trail,
        tissue_y_m=args.tissue_y,
        models_dirs=tuple(Path(d) for d in args.models_dir),
        zenoh=options_from_args(args),
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run the dashboard until SIGINT / SIGTERM; return the exit status."""
    args = build_parser().parse_args(argv)
    try:
        config = config_from_args(args)
        session = open_session(config.zenoh)
    except TeleopForceError as exc:
        print(f"dashboard: {exc}", file=sys.stderr)
        return 2
    try:
        dashboard = Dashboard(config, session)
        dashboard.start()
        if config.host not in ("127.0.0.1", "localhost", "::1"):
            print(
                f"dashboard: WARNING: listening on {config.host}: anyone who can reach this "
                "port can load models, record and replay (no authentication)",
                file=sys.stderr,
            )
        print(
            f"dashboard: http://{config.host}:{dashboard.server.get_port()} "
            f"(device {config.device}, master {config.master_device})",
            file=sys.stderr,
            flush=True,
        )

        def on_signal(_signum: int, _frame: object) -> None:
            dashboard.request_stop()

        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        with MemoryTrimmer():  # a long-running process: RSS follows what is live
            dashboard.wait()
        dashboard.stop()
    finally:
        session.close()
    return 0


__all__ = [
    "DEFAULT_PORT",
    "DEFAULT_TISSUE_Y_M",
    "Dashboard",
    "DashboardConfig",
    "build_parser",
    "main",
]
