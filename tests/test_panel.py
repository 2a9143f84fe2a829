"""`bioscara panel` driven headless by Textual's pilot against the simulated arm.

The model runs without threads here: button presses act at once and the arm cycles only when a
test steps it, in the simulator's virtual time, so every scenario is deterministic.
"""

from __future__ import annotations

import asyncio
import math
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import replace
from pathlib import Path

import pytest
from textual.widgets import Button, Input, Select

from bioscara import motion
from bioscara.arm import Lifecycle, Mode
from bioscara.bus.sim import SimBus
from bioscara.cli import main
from bioscara.communicator import Communicator
from bioscara.config import ArmConfig
from bioscara.hardware import open_arm, open_arm_bus, open_gripper
from bioscara.panel.app import JOG_STEP, PanelApp, _plot_groups
from bioscara.panel.model import SIGNALS, PanelModel
from bioscara.panel.screenshot import render_screenshot

SIZE = (160, 50)


def make_model(config: ArmConfig, *, threaded: bool = False) -> PanelModel:
    bus = open_arm_bus(config)
    return PanelModel(config, open_arm(config, bus), open_gripper(config, bus.monotonic), threaded=threaded)


@asynccontextmanager
async def panel(config: ArmConfig) -> AsyncIterator[tuple[PanelApp, PanelModel, object]]:
    model = make_model(config)
    app = PanelApp(model)
    try:
        async with app.run_test(size=SIZE) as pilot:
            yield app, model, pilot
    finally:
        model.close()


async def settle(app: PanelApp, pilot: object, model: PanelModel, predicate: Callable[[], bool],
                 seconds: float) -> bool:
    """Cycle the arm in 50 ms steps of virtual time until `predicate` holds (at most `seconds`)."""
    for _ in range(int(seconds / 0.05)):
        if predicate():
            break
        model.step(0.05)
    app.refresh_view()
    await pilot.pause()  # type: ignore[attr-defined]
    return predicate()


def label(app: PanelApp, selector: str) -> str:
    return str(app.query_one(selector).render())


def cell(app: PanelApp, joint: str, column: str) -> str:
    return str(app.query_one("#joints").get_cell(joint, column))


async def home_everything(app: PanelApp, model: PanelModel, pilot: object) -> None:
    await pilot.press("a")  # type: ignore[attr-defined]
    await pilot.press("a")  # type: ignore[attr-defined]
    assert model.arm.lifecycle is Lifecycle.ACTIVE
    await pilot.press("h")  # type: ignore[attr-defined]
    await pilot.press("H")  # type: ignore[attr-defined]
    assert await settle(app, pilot, model, lambda: all(aj.joint.is_homed() and not aj.command.home
                                                       for aj in model.arm.joints.values()), 60)
    await pilot.press("h")  # type: ignore[attr-defined]


def test_configure_activate_home_jog_go_to_and_stop(config: ArmConfig) -> None:
    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            assert "unconfigured" in label(app, "#arm-state")
            assert str(app.query_one("#arm-button").label) == "Configure"
            assert app.query_one("#homing-button").disabled  # needs the arm active
            await pilot.click("#arm-button")
            assert model.arm.lifecycle is Lifecycle.INACTIVE
            await settle(app, pilot, model, lambda: True, 0.1)
            assert str(app.query_one("#arm-button").label) == "Activate"
            await pilot.press("a")  # the same button's key (a second click this soon is a double click)
            await settle(app, pilot, model, lambda: True, 0.1)
            assert "active" in label(app, "#arm-state") and str(app.query_one("#arm-button").label) == "Deactivate"
            assert "Not Homed" in label(app, "#j1-homed")
            assert app.query_one("#j1-home-pos").disabled  # homing controller off

            await pilot.press("h")
            await settle(app, pilot, model, lambda: True, 0.1)
            assert all(aj.modes == {Mode.HOME} for aj in model.arm.joints.values())
            assert app.query_one("#position-button").disabled  # homing and position exclude each other
            await pilot.click("#home-all")
            assert await settle(app, pilot, model, lambda: all(aj.joint.is_homed() and not aj.command.home
                                                               for aj in model.arm.joints.values()), 60)
            assert all("Ready" in label(app, f"#{name}-homed") for name in model.arm.joints)
            await pilot.press("h")
            await pilot.press("p")
            await settle(app, pilot, model, lambda: True, 0.2)
            assert all(aj.modes == {Mode.POSITION} for aj in model.arm.joints.values())

            await pilot.press("3")
            start = model.arm["j3"].state.position
            await pilot.press("left")
            assert await settle(app, pilot, model,
                                lambda: abs(model.arm["j3"].state.position - (start - JOG_STEP["rad"])) < 2e-3, 10)
            assert cell(app, "j3", "mode") == "position"
            assert cell(app, "j3", "position").endswith(" rad") and cell(app, "j2", "position").endswith(" m")

            await pilot.click("#j1-goto")
            await pilot.press(*"-2.5", "enter")
            assert await settle(app, pilot, model, lambda: abs(model.arm["j1"].state.position + 2.5) < 2e-3, 20)

            await pilot.click("#j4-goto")
            await pilot.press(*"99", "enter")  # beyond the limit: refused, nothing moves
            await settle(app, pilot, model, lambda: True, 0.1)
            assert "outside" in model.messages[-1] and model.arm["j4"].command.position < 3.1

            await pilot.click("#j1-goto")
            await pilot.press(*"-1.0", "enter")
            await settle(app, pilot, model, lambda: abs(model.arm["j1"].state.velocity) > 0.05, 5)
            await pilot.press("escape")  # STOP: one key, from a focused input too
            assert model.messages[-1] == "STOP: done"
            assert await settle(app, pilot, model, lambda: all(abs(aj.state.velocity) < 1e-3
                                                               for aj in model.arm.joints.values()), 5)
            stopped_at = model.arm["j1"].state.position
            assert -2.45 > stopped_at > -1.0 - 1e-9 or -2.5 < stopped_at < -1.0
            model.step(2.0)
            assert model.arm["j1"].state.position == pytest.approx(stopped_at, abs=2e-3)  # stays stopped
            assert all(not aj.modes & {Mode.POSITION, Mode.VELOCITY} for aj in model.arm.joints.values())
    asyncio.run(scenario())


def test_a_stall_is_shown_as_a_fault_with_its_cause(config: ArmConfig) -> None:
    slow = replace(config.joints["j1"], max_velocity=0.36)  # 120 motor RPM: see the README on stalls
    config = replace(config, joints={**config.joints, "j1": slow})

    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            await home_everything(app, model, pilot)
            await pilot.press("p")
            await pilot.click("#j1-goto")
            await pilot.press(*"0.0", "enter")
            await settle(app, pilot, model, lambda: False, 1.5)
            bus = model.arm.bus
            assert isinstance(bus, SimBus)
            stepper = bus.joint(model.arm["j1"].config.address).stepper
            stepper.add_obstacle(stepper.rotor_angle() + 30.0, 1)
            assert await settle(app, pilot, model, lambda: model.arm.fault is not None, 5)
            assert cell(app, "j1", "fault") == "stall"
            assert "STALL" in cell(app, "j1", "flags")
            assert "fault: stall" in label(app, "#status")
            assert "inactive" in label(app, "#arm-state")  # the fault disabled the joints
    asyncio.run(scenario())


def test_a_joint_lost_and_regained(config: ArmConfig) -> None:
    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            await pilot.click("#arm-button")
            await pilot.press("a")
            await settle(app, pilot, model, lambda: True, 0.2)
            bus = model.arm.bus
            assert isinstance(bus, SimBus)
            sim_j3 = bus.joint(model.arm["j3"].config.address)
            sim_j3.connected = False  # the cable comes out
            assert await settle(app, pilot, model, lambda: model.view().joints[2].link != "ok", 1)
            assert cell(app, "j3", "link").startswith("lost: ")
            assert cell(app, "j3", "fault") == "lost link"
            assert "fault: lost link" in label(app, "#status")
            assert cell(app, "j1", "link").startswith("ok")  # the others keep reporting
            assert "inactive" in label(app, "#arm-state")
            sim_j3.connected = True
            assert await settle(app, pilot, model, lambda: model.view().joints[2].link == "ok", 1)
            assert cell(app, "j3", "link").startswith("ok") and cell(app, "j3", "fault") == ""
            await pilot.click("#arm-button")  # the operator activates again
            await settle(app, pilot, model, lambda: True, 0.2)
            assert model.arm.lifecycle is Lifecycle.ACTIVE
    asyncio.run(scenario())


def test_the_display_never_waits_for_the_bus(config: ArmConfig) -> None:
    """With the bus held by another thread, a button is queued and the display keeps refreshing."""
    config = replace(config, sim=replace(config.sim, realtime=True))  # the thread cycles at wall pace
    model = make_model(config, threaded=True)
    app = PanelApp(model)
    held, release = threading.Event(), threading.Event()
    timed_out: list[bool] = []

    def hold_the_bus() -> None:
        with model.arm.bus._lock:  # every transfer of the panel's threads waits for this
            held.set()
            timed_out.append(not release.wait(10))

    async def scenario() -> None:
        async with app.run_test(size=SIZE) as pilot:
            holder = threading.Thread(target=hold_the_bus)
            holder.start()
            assert held.wait(5)
            await pilot.click("#arm-button")
            for _ in range(3):
                app.refresh_view()
                await pilot.pause()
            assert not timed_out, "the display waited for the bus"
            assert model.arm.lifecycle is Lifecycle.UNCONFIGURED and model.busy == "configure"
            release.set()
            holder.join()
            for _ in range(500):  # the queued configure runs once the bus is free
                if model.arm.lifecycle is Lifecycle.INACTIVE:
                    break
                await asyncio.sleep(0.01)
            assert model.arm.lifecycle is Lifecycle.INACTIVE
    try:
        asyncio.run(scenario())
    finally:
        release.set()
        model.close()


def test_the_screenshot_command_draws_a_homed_arm(tmp_path: Path) -> None:
    out = tmp_path / "panel.svg"
    render_screenshot(out)
    svg = out.read_text(encoding="utf-8")
    assert svg.startswith("<svg") and "bioscara" in svg
    assert "Ready" in svg and "Deactivate" in svg


def test_panel_needs_a_terminal_or_web(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["panel"]) != 0  # pytest's stdout is not a terminal
    assert "needs a terminal" in capsys.readouterr().err
    assert main(["panel", "--rate", "0"]) != 0


KEYS = ("a", "g", "p", "h", "H", "1", "2", "3", "4", "left", "right", "tab", "t", "escape")


async def every_key_and_button(app: PanelApp, model: PanelModel, pilot: object) -> None:
    """Press every binding, then click every enabled button and submit every input; the arm cycles
    and the plot is redrawn (every signal, every group) after each. A crash ends `run_test` with it."""
    async def redraw() -> None:
        model.step(0.1)
        app.refresh_view()
        app.refresh_slow()
        await pilot.pause()  # type: ignore[attr-defined]
    for key in KEYS:
        await pilot.press(key)  # type: ignore[attr-defined]
        await redraw()
    for button in list(app.query(Button)):
        if not button.disabled and button.id is not None:
            await pilot.click(f"#{button.id}")  # type: ignore[attr-defined]
            await redraw()
    for box in list(app.query(Input)):
        for text in ("0.1", "x", "1e9"):
            await pilot.click(f"#{box.id}")  # type: ignore[attr-defined]
            await pilot.press(*text, "enter")  # type: ignore[attr-defined]
            await redraw()
    for selector, options in (("#signals", SIGNALS), ("#plotted", [value for _, value in _plot_groups(model)])):
        for option in options:
            app.query_one(selector, Select).value = option
            await redraw()
    await pilot.press("escape")  # type: ignore[attr-defined]
    await redraw()


@pytest.mark.parametrize("state", ["nothing configured", "j3 and j4 homed", "a joint unplugged", "a stall"])
def test_every_key_and_button_in_every_state(config: ArmConfig, state: str) -> None:
    """Tab, a, a, p with j1/j2 not homed used to end the panel in plotext's IndexError."""
    if state == "a stall":
        config = replace(config, joints={**config.joints, "j1": replace(config.joints["j1"], max_velocity=0.36)})

    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            bus = model.arm.bus
            assert isinstance(bus, SimBus)
            if state == "j3 and j4 homed":
                homed = open_arm(replace(config, joints={n: config.joints[n] for n in ("j3", "j4")}), bus)
                homed.configure()
                homed.activate()
                motion.home(homed, Communicator(homed, 100.0), timeout=120)
                homed.release()
                for key in ("tab", "a", "a", "p"):  # the crash of the issue
                    await pilot.press(key)
                    model.step(0.1)
                    app.refresh_view()
                    app.refresh_slow()
                    await pilot.pause()
                view = model.view()
                assert [j.homed for j in view.joints] == [False, False, True, True]
                assert all(math.isfinite(j.position) == j.homed for j in view.joints)
            elif state == "a joint unplugged":
                bus.joint(model.arm["j3"].config.address).connected = False
            elif state == "a stall":
                await home_everything(app, model, pilot)
                await pilot.press("p")
                await pilot.click("#j1-goto")
                await pilot.press(*"0.0", "enter")
                await settle(app, pilot, model, lambda: False, 1.0)
                stepper = bus.joint(model.arm["j1"].config.address).stepper
                stepper.add_obstacle(stepper.rotor_angle() + 30.0, 1)
                assert await settle(app, pilot, model, lambda: model.arm.fault is not None, 5)
            await every_key_and_button(app, model, pilot)
            assert app.is_running
    asyncio.run(scenario())


def test_unknown_until_read_first_focus_on_the_arm_and_every_known_joint_plotted(config: ArmConfig) -> None:
    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            assert not isinstance(app.focused, Input), "the keys act on the arm, they type nowhere"
            model.step(0.5)
            app.refresh_view()
            app.refresh_slow()
            await pilot.pause()
            assert all(cell(app, name, "flags") == "unknown" and cell(app, name, "homed") == "?"
                       for name in model.arm.joints), "not NOTHOMED|NOTENABLED before anything was read"
            assert all("unknown" in label(app, f"#{name}-homed") for name in model.arm.joints)
            assert app.plotted == [], "nothing plotted at 0.0 before the joints are read"
            await home_everything(app, model, pilot)
            # the display as the next cycles show it (the last key's action ran in the worker thread
            # after the view was drawn)
            await settle(app, pilot, model, lambda: False, 0.1)
            app.refresh_slow()
            await pilot.pause()
            assert app.plotted == ["j1", "j3", "j4"], "every rotary joint has its line"
            assert cell(app, "j1", "homed") == "yes" and "NOTENABLED" not in cell(app, "j1", "flags")
    asyncio.run(scenario())


def test_a_configured_arm_shows_no_position_before_its_first_read(config: ArmConfig) -> None:
    """Between configure and the cycle's first read the panel showed every joint at +0.0000 (a
    homed j1 included, wherever it stood): the arm's placeholders, not positions."""
    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            model.arm.configure()
            app.refresh_view()
            await pilot.pause()
            shown = [cell(app, name, column) for name in model.arm.joints for column in ("position", "velocity")]
            assert set(shown) == {"—"}, shown
            model.step(0.05)
            app.refresh_view()
            await pilot.pause()
            assert all(cell(app, name, "velocity").endswith("/s") for name in model.arm.joints), "read: shown"
    asyncio.run(scenario())


def test_the_plot_survives_samples_older_than_its_axis(config: ArmConfig) -> None:
    """A slow cycle (a loaded machine, the web panel) spreads the kept samples over more than the
    axis: a joint whose values all lie before it used to crash plotext (IndexError in _build.py)."""
    async def scenario() -> None:
        async with panel(config) as (app, model, pilot):
            span = model.samples.maxlen / model.comm.frequency  # type: ignore[operator]
            old = {"j1/position": 1.0, "j3/position": 2.0, "j4/position": 3.0}
            model.samples.extend((t, dict(old)) for t in (0.0, 1.0))
            model.samples.append((3 * span, {"j1/position": math.nan, "j3/position": 2.1, "j4/position": math.nan}))
            app.refresh_slow()
            await pilot.pause()
            assert app.plotted == ["j3"] and app.is_running
    asyncio.run(scenario())
