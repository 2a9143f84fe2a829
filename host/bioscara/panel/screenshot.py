"""Draw the panel of a homed, moving simulated arm to an SVG file: the screenshot in the docs.

`python -m bioscara.panel.screenshot docs/panel.svg` (what `make panel-screenshot` runs). The arm is
configured, activated, homed and sent moving in the simulator's virtual time, so the picture is the
same on every machine.
"""

from __future__ import annotations

import asyncio
from dataclasses import replace
import sys
from pathlib import Path

from ..arm import Mode
from ..config import read_config
from ..hardware import open_arm, open_arm_bus, open_gripper
from .app import PanelApp
from .model import PanelModel

SIZE = (160, 50)


def render_screenshot(path: Path) -> None:
    config = read_config()
    config = replace(config, bus=replace(config.bus, url="sim:virtual"))  # in this process, in virtual time
    bus = open_arm_bus(config)
    model = PanelModel(config, open_arm(config, bus), open_gripper(config, bus.monotonic), threaded=False)
    app = PanelApp(model)

    async def draw() -> None:
        async with app.run_test(size=SIZE) as pilot:
            for key in ("a", "a", "g", "g", "h", "H"):
                await pilot.press(key)
                model.step(0.05)
            for _ in range(1200):
                if all(aj.joint.is_homed() and not aj.command.home for aj in model.arm.joints.values()):
                    break
                model.step(0.05)
            model.toggle_controller(Mode.HOME)
            model.toggle_controller(Mode.POSITION)
            model.set_gripper(0.02)
            model.go_to("j1", -1.5)
            model.go_to("j3", 1.8)
            for _ in range(60):  # 3 s of the move, sampled for the plot as the display would
                model.step(0.05)
                model.view()
            app.refresh_view()
            app.refresh_slow()
            await pilot.pause()
            path.parent.mkdir(parents=True, exist_ok=True)
            app.save_screenshot(path.name, str(path.parent))
    try:
        asyncio.run(draw())
    finally:
        model.close()


if __name__ == "__main__":
    render_screenshot(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/panel.svg"))
