"""The panel's screen (Textual): what the original RViz panel shows and does, plus STOP, jog,
go-to, the gripper width and a live plot. Keyboard first; every button also takes the mouse.

The screen only reads `PanelModel.view()` on a timer and hands button presses to the model, which
runs them off the display's thread: a slow or missing joint never freezes the display.
"""

from __future__ import annotations

import asyncio
import math
import sys
import textwrap
from collections.abc import Callable
from signal import SIG_IGN, SIGINT, Signals, getsignal

from textual import events, on
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.css.query import NoMatches
from textual.driver import Driver
from textual.widgets import Button, DataTable, Footer, Header, Input, Label, Log, Select, Static
from textual_plotext import PlotextPlot

from ..arm import Mode
from .model import SIGNALS, JointView, PanelModel

REFRESH_S = 0.1
SLOW_REFRESH_S = 0.5
JOG_STEP = {"rad": 0.05, "m": 0.002}  # one jog press, joint units
_STATE_STYLE = {"active": "bold green", "inactive": "bold", "unconfigured": "bold dark_orange",
                "finalized": "bold red", "none": "dim"}
_ACTION_VARIANT = {"configure": "warning", "activate": "success", "deactivate": "error"}
_COLUMNS = {"joint": 5, "position": 13, "velocity": 15, "command": 13, "mode": 8, "flags": 27,
            "homed": 5, "fault": 18, "link": 26}
HOME_LABELS = {"prismatic": ("↓", "○", "↑"), "revolute": ("↻", "○", "↺")}  # toward -, stop, toward +
_UNIT_LABEL = {"position": "{u}", "velocity": "{u}/s", "following_error": "{u}"}


def _fmt(value: float, unit: str, digits: int = 4) -> str:
    return "—" if not math.isfinite(value) else f"{value:+.{digits}f} {unit}"


def _plot_groups(model: PanelModel) -> list[tuple[str, str]]:
    """What the plot can show together: the joints of one unit, or each joint alone."""
    joints = model.arm.joints
    rotary = [name for name, aj in joints.items() if aj.config.type != "prismatic"]
    groups = [(f"rotary joints {' '.join(rotary)} (rad)", " ".join(rotary))] if len(rotary) > 1 else []
    return groups + [(f"{name} ({'m' if aj.config.type == 'prismatic' else 'rad'})", name)
                     for name, aj in joints.items()]


class StateRow(Horizontal):
    """A lifecycle row: name, state label, and the one button that state allows."""

    def __init__(self, title: str, key: str) -> None:
        super().__init__(classes="state-row")
        self.title = title
        self.key = key

    def compose(self) -> ComposeResult:
        yield Label(self.title, classes="row-title")
        yield Label("", id=f"{self.key}-state", classes="state")
        yield Button("-", id=f"{self.key}-button", classes="state-button", disabled=True)


class JointControls(Horizontal):
    """Per joint: homing toward either end stop and its stop, the homed label, jog and go-to."""

    def __init__(self, name: str, prismatic: bool) -> None:
        super().__init__(classes="joint-row")
        self.joint = name
        self.prismatic = prismatic

    def compose(self) -> ComposeResult:
        name = self.joint
        minus, stop, plus = HOME_LABELS["prismatic" if self.prismatic else "revolute"]
        yield Label(name, classes="row-title")
        yield Button(minus, id=f"{name}-home-neg", classes="small")
        yield Button(stop, id=f"{name}-home-stop", classes="small")
        yield Button(plus, id=f"{name}-home-pos", classes="small")
        yield Label("", id=f"{name}-homed", classes="homed")
        yield Button("◀ jog", id=f"{name}-jog-neg", classes="small")
        yield Button("jog ▶", id=f"{name}-jog-pos", classes="small")
        yield Input(placeholder=f"go to ({'m' if self.prismatic else 'rad'})", id=f"{name}-goto",
                    classes="goto")


class PanelApp(App[None]):
    """`bioscara panel`: the arm's control panel."""

    TITLE = "bioscara panel"
    AUTO_FOCUS = "#joints"  # the arm, not a text box: the keys (a, p, h, ...) act at once
    CSS = """
    #top { height: auto; }
    #states { width: 1fr; height: auto; border: round $accent; padding: 0 1; }
    #comm { width: 44; height: auto; border: round $accent; padding: 0 1; }
    .state-row, .joint-row { height: 3; }
    .row-title { width: 18; padding: 1 0; }
    .state { width: 14; padding: 1 0; }
    .state-button { min-width: 14; }
    .small { min-width: 7; }
    .homed { width: 11; padding: 1 1; }
    .goto { width: 18; }
    #gripper-width { width: 20; }
    #stop { min-width: 16; margin: 0 1; }
    #joints { height: 6; }
    #controls { height: auto; border: round $accent; }
    #bottom { height: 1fr; min-height: 8; }
    #plot { width: 2fr; }
    #side { width: 1fr; }
    #signals { width: 100%; }
    #plotted { width: 100%; }
    #log { height: 1fr; border: round $accent; }
    """
    BINDINGS = [
        Binding("escape", "stop", "STOP", priority=True),
        Binding("a", "lifecycle", "arm configure/activate/deactivate"),
        Binding("g", "gripper_lifecycle", "gripper"),
        Binding("p", "position_control", "position ctl"),
        Binding("h", "homing_control", "homing ctl"),
        Binding("H", "home_all", "home all"),
        Binding("left", "jog(-1)", "jog -", show=False),
        Binding("right", "jog(1)", "jog +", show=False),
        Binding("t", "go_to", "go to"),
        Binding("q", "quit", "quit"),
        Binding("ctrl+c", "interrupt", "stop and quit", show=False, priority=True),
    ]

    def __init__(self, model: PanelModel, end_on: tuple[Signals, ...] = ()) -> None:
        """`end_on`: signals that end the panel (the command's: SIGINT, SIGTERM, SIGHUP); the one
        that did is `ended_by`."""
        super().__init__()
        self.model = model
        self.end_on = end_on
        self.ended_by: Signals | None = None
        self.selected = next(iter(model.arm.joints))
        self._messages_shown = 0
        self.plotted: list[str] = []  # the joints the plot draws now (those with values to draw)
        self._shown: dict[str, object] = {}  # what each widget shows now, by selector
        self._home_labels = {name: HOME_LABELS[aj.config.type] for name, aj in model.arm.joints.items()}

    # ---- layout ----

    def compose(self) -> ComposeResult:
        model = self.model
        yield Header(show_clock=False)
        with Horizontal(id="top"):
            with Vertical(id="states"):
                yield StateRow("Arm", "arm")
                with Horizontal(classes="state-row"):
                    yield Label("Gripper", classes="row-title")
                    yield Label("", id="gripper-state", classes="state")
                    yield Button("-", id="gripper-button", classes="state-button", disabled=True)
                    yield Input(placeholder="width (mm)", id="gripper-width")
                yield StateRow("Position control", "position")
                yield StateRow("Homing control", "homing")
            with Vertical(id="comm"):
                yield Static("", id="comm-stats")
                yield Static("", id="status")
                yield Button("STOP (Esc)", id="stop", variant="error")
        yield DataTable(id="joints", cursor_type="row", zebra_stripes=True)
        with Vertical(id="controls"):
            for name, aj in model.arm.joints.items():
                yield JointControls(name, aj.config.type == "prismatic")
            with Horizontal(classes="joint-row"):
                yield Button("home all (H)", id="home-all")
                yield Label("", id="homing-hint", classes="hint")
        with Horizontal(id="bottom"):
            yield PlotextPlot(id="plot")
            with Vertical(id="side"):
                yield Select([(signal.replace("_", " "), signal) for signal in SIGNALS], value="position",
                             allow_blank=False, id="signals")
                yield Select(_plot_groups(model), value=_plot_groups(model)[0][1], allow_blank=False, id="plotted")
                yield Log(id="log", highlight=False)
        yield Footer()

    def get_driver_class(self) -> type[Driver]:
        driver = super().get_driver_class()
        if sys.platform == "win32":  # Textual's Windows driver (terminal.py needs termios)
            return driver
        from textual.drivers.linux_driver import LinuxDriver

        from .terminal import PanelDriver
        return PanelDriver if driver is LinuxDriver else driver  # not textual-serve's, for --web

    def on_mount(self) -> None:
        self.sub_title = self.model.arm.bus.describe()
        # Through the event loop, not an exception raised wherever the main thread is: raised in a
        # finalizer (asyncio runs many), an exception is printed and dropped, and the panel ran on.
        loop = asyncio.get_running_loop()
        for signum in self.end_on:
            if getsignal(signum) is not SIG_IGN:
                loop.add_signal_handler(signum, self._end_by, signum)
        table = self.query_one("#joints", DataTable)
        for column, width in _COLUMNS.items():
            table.add_column(column, key=column, width=width)
        for name in self.model.arm.joints:
            table.add_row(*([name] + [""] * (len(_COLUMNS) - 1)), key=name)
        self.refresh_view()
        self.refresh_slow()
        self.set_interval(REFRESH_S, lambda: self._on_timer(self.refresh_view))
        self.set_interval(SLOW_REFRESH_S, lambda: self._on_timer(self.refresh_slow))

    def action_interrupt(self) -> None:
        """Ctrl-C typed in the panel (its terminal is raw: a key, not a signal) ends it as SIGINT
        does: the arm stopped, where each joint stopped said, exit status 130."""
        self._end_by(SIGINT)

    def _end_by(self, signum: Signals) -> None:
        if self.ended_by is None:
            self.ended_by = signum
            self.exit()

    def _on_timer(self, refresh: Callable[[], None]) -> None:
        try:
            refresh()
        except NoMatches:  # the widgets never change: only a tick while the app closes gets here
            pass

    # ---- display: widgets are touched only when what they show changes (each change re-lays out) ----

    def _text(self, selector: str, text: str) -> None:
        if self._shown.get(selector) != text:
            self._shown[selector] = text
            self.query_one(selector, Static).update(text)

    def _button(self, selector: str, label: str, disabled: bool, variant: str = "default") -> None:
        state = (label, disabled, variant)
        if self._shown.get(selector) != state:
            self._shown[selector] = state
            button = self.query_one(selector, Button)
            button.label = label
            button.disabled = disabled
            button.variant = variant  # type: ignore[assignment]

    def _cell(self, table: DataTable, row: str, column: str, text: str) -> None:
        key = f"{row}/{column}"
        if self._shown.get(key) != text:
            self._shown[key] = text
            table.update_cell(row, column, text)

    def refresh_view(self) -> None:
        view = self.model.view()
        self._show_state("arm", view.lifecycle, self.model.lifecycle_action())
        self._show_state("gripper", view.gripper, self.model.gripper_action())
        self._show_controller("position", view.position_control, view.can_position)
        self._show_controller("homing", view.homing_control, view.can_homing)
        busy = f"busy: {view.busy}" if view.busy else ""
        fault = f"[b red]fault: {view.fault}[/]" if view.fault else ""
        self._text("#status", "\n".join(filter(None, (f"selected {self.selected}", busy, fault))))
        table = self.query_one("#joints", DataTable)
        for joint in view.joints:
            self._show_joint(table, joint, view.homing_control)
        self._text("#homing-hint", "" if view.homing_control else "Activate the homing controller to start homing.")
        log = self.query_one("#log", Log)
        unseen = min(self.model.said - self._messages_shown, len(self.model.messages))
        width = max(20, log.scrollable_content_region.width - 1)  # the scroll bar's column
        for message in list(self.model.messages)[len(self.model.messages) - unseen:]:
            # wrapped: a refusal names who commands the arm and how to take over, past the box's width
            log.write_lines(textwrap.wrap(message, width) or [""])
        self._messages_shown = self.model.said

    def _show_state(self, key: str, state: str, action: str | None) -> None:
        self._text(f"#{key}-state", f"[{_STATE_STYLE.get(state, 'bold')}]{state}[/]")
        self._button(f"#{key}-button", action.capitalize() if action else "-", action is None,
                     _ACTION_VARIANT.get(action or "", "default"))

    def _show_controller(self, key: str, active: bool, allowed: bool) -> None:
        state = "active" if active else "inactive"
        self._text(f"#{key}-state", f"[{_STATE_STYLE[state]}]{state}[/]")
        self._button(f"#{key}-button", "Deactivate" if active else "Activate", not (active or allowed),
                     "error" if active else "success")

    def _show_joint(self, table: DataTable, joint: JointView, homing: bool) -> None:
        row = joint.name
        cells = {
            "joint": ("▶ " if joint.name == self.selected else "  ") + joint.name,
            "position": _fmt(joint.position, joint.unit),
            "velocity": _fmt(joint.velocity, joint.unit + "/s"),
            "command": _fmt(joint.command, joint.unit),
            "mode": joint.mode,
            "flags": f"0x{joint.flags:02x} {joint.flag_names}" if joint.known else "unknown",
            "homed": ("yes" if joint.homed else "no") if joint.known else "?",
            "fault": joint.fault or "",
            "link": joint.link if joint.link != "ok" else f"ok ({joint.transactions} tx, {joint.lost} lost)",
        }
        for column, value in cells.items():
            self._cell(table, row, column, value)
        self._text(f"#{row}-homed", "[dim]unknown[/]" if not joint.known else
                   "[b green]Ready[/]" if joint.homed else "[b red]Not Homed[/]")
        for suffix, label in zip(("neg", "stop", "pos"), self._home_labels[row]):
            self._button(f"#{row}-home-{suffix}", label, not homing)

    def refresh_slow(self) -> None:
        """The communicator's statistics and the plot: twice a second is enough to read them."""
        stats = self.model.comm.stats
        self._text("#comm-stats", f"communicator {stats.rate:6.1f} Hz\njitter {stats.jitter * 1e6:8.0f} µs  "
                   f"overruns {stats.overruns}")
        self.refresh_plot()

    def refresh_plot(self) -> None:
        """The chosen quantity of the chosen joints over the kept history, on one axis in their unit."""
        signal = str(self.query_one("#signals", Select).value)
        names = str(self.query_one("#plotted", Select).value).split()
        plot = self.query_one("#plot", PlotextPlot)
        plt = plot.plt
        plt.clear_data()
        plt.clear_figure()
        samples = list(self.model.samples)
        now = samples[-1][0] if samples else 0.0
        span = self.model.samples.maxlen / self.model.comm.frequency
        plotted: list[str] = []
        for name in names:
            # Only finite points inside the time axis: plotext fails on a labelled series it cannot
            # place (all NaN, or older than the axis, as a slow cycle leaves them).
            points = [(t - now, v[f"{name}/{signal}"]) for t, v in samples
                      if t - now >= -span and math.isfinite(v.get(f"{name}/{signal}", math.nan))]
            if points:
                xs, ys = zip(*points)
                plt.plot(xs, ys, label=name)
                plotted.append(name)
        self.plotted = plotted
        unit = "m" if self.model.arm[names[0]].config.type == "prismatic" else "rad"
        plt.xlim(-span, 0)
        plt.title(f"{signal.replace('_', ' ')} ({_UNIT_LABEL[signal].format(u=unit)}), last {span:g} s")
        plt.xlabel("time (s)")
        plt.ylabel(_UNIT_LABEL[signal].format(u=unit))
        plot.refresh()

    # ---- actions ----

    @on(Button.Pressed)
    def _pressed(self, event: Button.Pressed) -> None:
        key = event.button.id or ""
        model = self.model
        if key == "stop":
            self.action_stop()
        elif key == "arm-button":
            model.lifecycle()
        elif key == "gripper-button":
            model.gripper_lifecycle()
        elif key == "position-button":
            model.toggle_controller(Mode.POSITION)
        elif key == "homing-button":
            model.toggle_controller(Mode.HOME)
        elif key == "home-all":
            model.home_all()
        elif "-home-" in key:
            name, _, direction = key.split("-")
            model.home(name, {"neg": -1, "stop": 0, "pos": 1}[direction])
        elif "-jog-" in key:
            name, _, direction = key.split("-")
            self.selected = name
            self.action_jog(-1 if direction == "neg" else 1)
        self.refresh_view()

    @on(Input.Submitted)
    def _submitted(self, event: Input.Submitted) -> None:
        key = event.input.id or ""
        try:
            value = float(event.value)
        except ValueError:
            self.model.say(f"not a number: {event.value!r}")
            return
        if not math.isfinite(value):
            self.model.say(f"not a finite number: {event.value!r}")
            return
        if key == "gripper-width":
            self.model.set_gripper(value / 1000.0)
        elif key.endswith("-goto"):
            self.selected = key.split("-")[0]
            self.model.go_to(self.selected, value)
        event.input.value = ""
        self.refresh_view()

    @on(Select.Changed, "#signals")
    @on(Select.Changed, "#plotted")
    def _signal_changed(self) -> None:
        self.refresh_plot()

    def action_stop(self) -> None:
        self.model.stop()

    def action_lifecycle(self) -> None:
        self.model.lifecycle()

    def action_gripper_lifecycle(self) -> None:
        self.model.gripper_lifecycle()

    def action_position_control(self) -> None:
        self.model.toggle_controller(Mode.POSITION)

    def action_homing_control(self) -> None:
        self.model.toggle_controller(Mode.HOME)

    def action_home_all(self) -> None:
        self.model.home_all()

    def on_key(self, event: events.Key) -> None:
        """1..4 select the joint that jog (left/right arrows) moves."""
        if event.key in ("1", "2", "3", "4") and not isinstance(self.focused, Input):
            names = list(self.model.arm.joints)
            index = int(event.key) - 1
            if index < len(names):
                self.selected = names[index]
                self.refresh_view()

    def action_go_to(self) -> None:
        """Into the selected joint's go-to box, from the keyboard (Tab would pass every button
        before it): the target typed there and Enter move the joint."""
        self.query_one(f"#{self.selected}-goto", Input).focus()
        unit = "m" if self.model.arm[self.selected].config.type == "prismatic" else "rad"
        self.model.say(f"go to: type {self.selected}'s target ({unit}), then Enter")

    def action_jog(self, direction: int) -> None:
        aj = self.model.arm[self.selected]
        unit = "m" if aj.config.type == "prismatic" else "rad"
        self.model.jog(self.selected, direction * JOG_STEP[unit])
